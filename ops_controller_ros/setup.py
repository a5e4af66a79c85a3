from setuptools import find_packages, setup

package_name = "ops_controller_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools", "numpy", "numba"],
    zip_safe=True,
    maintainer="OPS developers",
    maintainer_email="ops-dev@example.com",
    description="SPGD-PID controller and learned-policy runner nodes for the OPS simulator.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "spgd = ops_controller_ros.spgd_node:main",
            "policy = ops_controller_ros.policy_node:main",
            "tracker = ops_controller_ros.tracker_node:main",
        ],
    },
)
