from setuptools import find_packages, setup

package_name = "ops_sim_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools", "numpy", "gymnasium", "matplotlib", "threadpoolctl"],
    zip_safe=True,
    maintainer="OPS developers",
    maintainer_email="ops-dev@example.com",
    description="Optical pulse stacking simulator, Gymnasium env, simulator and monitor nodes.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim = ops_sim_ros.sim_node:main",
            "monitor = ops_sim_ros.monitor_node:main",
            "foxglove = ops_sim_ros.foxglove_node:main",
        ],
    },
)
