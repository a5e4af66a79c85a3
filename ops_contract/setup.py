from setuptools import find_packages, setup

package_name = "ops_contract"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools", "numpy", "pyyaml", "threadpoolctl"],
    zip_safe=True,
    maintainer="OPS developers",
    maintainer_email="ops-dev@example.com",
    description="The OPS contract: config, node parameters, topics and QoS, observation, rig file.",
    license="Apache-2.0",
)
