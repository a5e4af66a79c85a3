from setuptools import find_packages, setup

package_name = "ops_rig_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools", "numpy", "pyyaml", "pyvisa", "pyvisa-py", "pyserial"],
    zip_safe=True,
    maintainer="OPS developers",
    maintainer_email="ops-dev@example.com",
    description="The rig node, instrument drivers, calibration and a simulated lab.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "rig = ops_rig_ros.rig_node:main",
            "calibrate = ops_rig_ros.calibrate:main",
            "simlab = ops_rig_ros.simlab.main:main",
        ],
    },
)
