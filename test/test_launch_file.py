"""The launch file names executables and parameter files that exist (no ``launch`` here)."""

import ast
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "launch" / "policy_align.launch.py"


def _constant(tree: ast.Module, name: str):
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name
                                                for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError(f"{LAUNCH.name} defines no {name}")


def test_launch_file_names_installed_executables_and_parameter_files():
    tree = ast.parse(LAUNCH.read_text())
    names = list(_constant(tree, "CORE_NODES")) + list(_constant(tree, "OPTIONAL_NODES").values())
    assert {"recorder", "learner", "executor", "sim_robot"} <= set(names)
    setup = (ROOT / "setup.py").read_text()
    scripts = set(re.findall(r'"(\w+) = policy_align_ros\.nodes\.\w+:main"', setup))
    for name in names:
        assert name in scripts, f"no console script {name}"
        params = yaml.safe_load((ROOT / "config" / f"{name}.yaml").read_text())
        assert "ros__parameters" in params[name], f"config/{name}.yaml is not for {name}"
    assert 'glob("launch/*.launch.py")' in setup
    assert "def generate_launch_description" in LAUNCH.read_text()
