from setuptools import find_packages, setup

package_name = "ops_gym_bridge"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=[
        "setuptools",
        "numpy",
        "gymnasium",
    ],
    zip_safe=True,
    maintainer="OPS developers",
    maintainer_email="ops-dev@example.com",
    description="Gymnasium env over the simulator topics; the harness's commands under its name.",
    license="Apache-2.0",
    # The harness's commands under this package's name too (``ros2 run ops_gym_bridge train``, as
    # the design names them); the code is ops_experiments'.
    entry_points={
        "console_scripts": [
            "train = ops_experiments.train:main",
            "evaluate = ops_experiments.evaluate:main",
            "benchmark = ops_experiments.table1.benchmark:main",
            "report = ops_experiments.table1.report:main",
            "realism_sweep = ops_experiments.realism_sweep:main",
            "distill = ops_experiments.distill:main",
        ],
    },
)
