from glob import glob

from setuptools import find_packages, setup

package_name = "ops_experiments"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["yaml/*.yaml"]},
    include_package_data=True,
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/yaml", glob("ops_experiments/yaml/*.yaml")),
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
    description="The experiment harness (train, evaluate, realism sweep) and the paper's Table 1.",
    license="Apache-2.0",
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
