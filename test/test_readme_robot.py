"""README's "Use it on your robot" commands run on a simulated robot (domain id 227).

The block after ``<!-- test: robot NAME -->`` is run line by line as written, in a scratch
directory (its relative paths land there), with two documented substitutions: the
simulated robot (``sim_robot`` named ``velocity_controller``, so the executor's controller
check reads its joints) stands in for the user's driver and controller, and the scripted
``demonstrator``, which makes the same ``/recorder/start_demo`` and ``/recorder/stop_demo``
calls, stands in for the person moving the robot between them. ``~/enable`` is retried
until the executor holds a fresh joint state.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from policy_align_ros.kinematics.robot_config import load_robot_config
from policy_align_ros.learning.policy_file import read_robot_fields

ROOT = Path(__file__).resolve().parents[1]
MARKER = r"<!-- test: robot (\w+) -->\n```bash\n(.*?)```"
#: Demonstrations the stand-in teacher records (fewer give a model the learner refuses).
DEMOS = 8


def _robot_block() -> tuple[str, list[str]]:
    found = re.findall(MARKER, (ROOT / "README.md").read_text(), re.S)
    assert len(found) == 1, "README.md needs one block marked <!-- test: robot NAME -->"
    robot, body = found[0]
    lines = [line.split("  #")[0].strip() for line in body.splitlines()]
    return robot, [line for line in lines if line]


def _script(robot: str, lines: list[str]) -> str:
    """The block as a bash script with the substitutions of the module docstring."""
    bracket = [line for line in lines if "/recorder/st" in line]
    assert [line.split()[-1] for line in bracket] == ["/recorder/start_demo",
                                                      "/recorder/stop_demo"], bracket
    record, learn, execute, enable = [line for line in lines if line not in bracket]
    assert record.startswith("recorder ") and execute.startswith("executor "), lines
    return "\n".join([
        "trap 'kill $(jobs -p) 2>/dev/null; wait' EXIT",
        f"sim_robot --ros-args -r __node:=velocity_controller -p robot_config:={robot} &",
        record,
        f"demonstrator --ros-args -p robot_config:={robot} -p num_demos:={DEMOS}",
        learn,
        execute,
        "armed=no",
        f"for _ in $(seq 20); do {enable} && {{ armed=yes; break; }}; sleep 0.5; done",
        '[ "$armed" = yes ]',
    ])


def test_use_it_on_your_robot_commands_arm_the_executor(tmp_path):
    robot, lines = _robot_block()
    env = dict(os.environ, ROS_DOMAIN_ID="227", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env["PATH"] = f"{ROOT / '.venv' / 'bin'}{os.pathsep}{Path(sys.executable).parent}" \
                  f"{os.pathsep}{env.get('PATH', '')}"
    script = _script(robot, lines)
    result = subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=tmp_path,
                            env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, (
        f"README robot block failed ({result.returncode}):\n{script}\n--- stdout\n"
        f"{result.stdout[-3000:]}\n--- stderr\n{result.stderr[-3000:]}")
    config = load_robot_config(robot)
    assert read_robot_fields(tmp_path / "model.npz") == (config.robot, config.joints)
    assert (tmp_path / "fit.png").read_bytes()[:4] == b"\x89PNG"  # learn's --plot
