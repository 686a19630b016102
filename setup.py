"""ament_python build of policy_align_ros (colcon) and pip install (virtual environment)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "policy_align_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        # Robot configs (robot, joints, controller, frames) read by every node.
        (f"share/{PACKAGE}/config/robots", glob("config/robots/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="policy_align_ros developers",
    maintainer_email="policy-align-ros@example.com",
    description="Learn potential-based motion policies from constrained demonstrations "
    "(PolicyAlign) and execute them under new constraints.",
    license="Apache-2.0",
    tests_require=["pytest"],
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "policy-align = policy_align_ros.cli:main",
            "recorder = policy_align_ros.nodes.recorder:main",
            "learner = policy_align_ros.nodes.learner:main",
            "executor = policy_align_ros.nodes.executor:main",
            "sim_robot = policy_align_ros.nodes.sim_robot:main",
            "demonstrator = policy_align_ros.nodes.demonstrator:main",
        ],
    },
)
