"""The docs match the code: parameter tables, commands, and the blocks marked runnable.

* The parameter tables are regenerated from the nodes' descriptors (domain id 230) and must
  equal the block of ``docs/parameters.md``.
* Lines that cannot run here (``ros2 run``, ``ros2 launch``, ``colcon``, ``make``), in the
  README and every page under ``docs/``, are checked statically: the executables, launch
  files, parameter files, make targets and ``policy-align`` subcommands they name exist.
* Bash blocks preceded by ``<!-- test: run ... -->`` are run as pasted, with the environment
  variables given in the marker (small sizes), and must exit 0.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
PARAMETERS = (ROOT / "docs" / "parameters.md").read_text()
sys.path.insert(0, str(ROOT / "tools"))


def _entry_points() -> set[str]:
    text = (ROOT / "setup.py").read_text()
    return set(re.findall(r'"([\w-]+) = policy_align_ros', text))


def _documents() -> list[str]:
    """README.md and every page under docs/ (benchmarks, design notes, ...)."""
    return [README] + [path.read_text() for path in sorted((ROOT / "docs").rglob("*.md"))]


def _code_lines() -> list[str]:
    lines = []
    for text in _documents():
        for block in re.findall(r"```[a-z]*\n(.*?)```", text, re.S):
            lines.extend(line.strip() for line in block.splitlines())
        # Inline code spans carry commands too (e.g. in the graph section's bullet points).
        lines.extend(re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", text, flags=re.S)))
    return lines


def _words(line: str) -> list[str]:
    try:
        return shlex.split(line.replace("\\", ""), comments=True)
    except ValueError:  # an inline span holding part of a quoted argument
        return line.split()


def test_parameter_tables_match_the_nodes_descriptors():
    from policy_align_ros.client.param_table import parameter_tables

    block = re.search(r"<!-- BEGIN params -->\n(.*?)\n<!-- END params -->", PARAMETERS, re.S)
    assert block, "docs/parameters.md has no params block"
    generated = parameter_tables(domain_id=230)
    assert block.group(1) == generated, (
        "docs/parameters.md is stale: run `python tools/update_readme.py --params`")


def test_ros2_and_colcon_lines_name_what_exists():
    executables = _entry_points()
    checked = 0
    for line in _code_lines():
        words = _words(line)
        for i, word in enumerate(words[:-2]):
            if word == "ros2" and words[i + 1] == "run":
                assert words[i + 2] == "policy_align_ros", line
                assert words[i + 3] in executables, f"no executable {words[i + 3]!r}: {line}"
                checked += 1
            if word == "ros2" and words[i + 1] == "launch":
                assert (ROOT / "launch" / words[i + 3]).exists(), line
                checked += 1
        for i, word in enumerate(words[:-1]):
            if word == "--params-file":
                name = Path(words[i + 1]).name
                assert (ROOT / "config" / name).exists(), f"no config/{name}: {line}"
            if word == "--packages-select":
                assert words[i + 1] == "policy_align_ros", line
    assert checked >= 2


def test_make_targets_and_cli_subcommands_exist():
    makefile = (ROOT / "Makefile").read_text()
    targets = set(re.findall(r"^([\w-]+):", makefile, re.M))
    cli = (ROOT / "policy_align_ros" / "cli.py").read_text()
    commands = set(re.findall(r'add_parser\(\s*"([\w-]+)"', cli))
    seen = 0
    for line in _code_lines():
        words = line.split()
        if len(words) >= 2 and words[0] == "make":
            assert words[1] in targets, f"no make target {words[1]!r}: {line}"
            seen += 1
        if len(words) >= 2 and words[0] == "policy-align" and not words[1].startswith("-"):
            sub = words[1].split("|")[0]
            assert sub in commands, f"no policy-align subcommand {sub!r}: {line}"
            seen += 1
    assert seen >= 5


def _runnable_blocks() -> list[tuple[dict[str, str], str]]:
    found = []
    pattern = r"<!-- test: run ?(.*?) -->\n```(?:bash|sh)\n(.*?)```"
    for env_text, body in re.findall(pattern, README, re.S):
        env = dict(item.split("=", 1) for item in shlex.split(env_text))
        found.append((env, body))
    return found


@pytest.mark.parametrize("index", range(len(_runnable_blocks())))
def test_runnable_block_exits_zero(index, tmp_path):
    env_over, body = _runnable_blocks()[index]
    env = dict(os.environ)
    env["PATH"] = f"{ROOT / '.venv' / 'bin'}{os.pathsep}{Path(sys.executable).parent}" \
                  f"{os.pathsep}{env.get('PATH', '')}"
    env.update(env_over)
    env.setdefault("WORK", str(tmp_path))
    result = subprocess.run(["bash", "-euo", "pipefail", "-c", body], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, (
        f"README block {index} failed ({result.returncode}):\n{body}\n--- stdout\n"
        f"{result.stdout[-3000:]}\n--- stderr\n{result.stderr[-3000:]}")
