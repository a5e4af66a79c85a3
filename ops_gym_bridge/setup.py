from glob import glob

from setuptools import find_packages, setup

package_name = "ops_gym_bridge"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["hyperparams/*.yaml"]},
    include_package_data=True,
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/hyperparams", glob("ops_gym_bridge/hyperparams/*.yaml")),
    ],
    install_requires=[
        "setuptools",
        "numpy",
        "gymnasium",
        "stable-baselines3",
        "pyyaml",
        "tqdm",
        "matplotlib",
    ],
    zip_safe=True,
    maintainer="OPS developers",
    maintainer_email="ops-dev@example.com",
    description="Gymnasium env over the simulator topics; train, evaluate and benchmark CLIs.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "train = ops_gym_bridge.experiments.train:main",
            "evaluate = ops_gym_bridge.experiments.evaluate:main",
            "benchmark = ops_gym_bridge.table1.benchmark:main",
            "report = ops_gym_bridge.table1.report:main",
            "realism_sweep = ops_gym_bridge.experiments.realism_sweep:main",
        ],
    },
)
