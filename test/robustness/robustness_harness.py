"""The robustness harness: result rows, the lab (scratch space, domain ids), command runs.

Every case builds its bad input, feeds it to the package the way a user would (the
``policy-align`` command, a rosbag2 dataset, a parameter set through the node's
``set_parameters`` service, a message on the node's topic, a service call), observes what the
package did and checks it against what a robot owner expects (a ``Result`` row). Nothing
decides a pass on wall-clock speed: waits poll a condition and only bound a failure.

The cases are in ``robustness_cases_*.py``, the ROS rigs in ``robustness_rigs.py``, and the
table of ``docs/robustness.md`` is printed by ``robustness_table.py``.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import subprocess
import sys
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# The console scripts of this interpreter's environment (the venv), else those on PATH.
BIN = Path(sys.executable).parent
if not (BIN / "policy-align").exists() and shutil.which("policy-align"):
    BIN = Path(shutil.which("policy-align")).parent
TRACEBACK = "Traceback (most recent call last)"
AREAS = ("cli", "bags", "parameters", "messages", "services")
J2 = ["j1", "j2"]
T0 = 1_700_000_000 * 10**9
MS = 10**6
#: The left arm of TALOS, the joints of the sim_robot, demonstrator and executor rigs.
ARM = [f"arm_left_{i}_joint" for i in range(1, 8)]


# --- results ----------------------------------------------------------------------------
@dataclass
class Result:
    """One row of the table.

    ``problems`` lists each expectation that did not hold (empty: the behaviour is the one
    a robot owner expects); ``lost`` is the number of finished demonstrations lost (None
    when none is involved); ``data`` keeps the raw observations for tests.
    """

    case: str
    area: str
    tried: str
    behaviour: str = ""
    crash: bool = False
    traceback: bool = False
    lost: int | None = None
    problems: list[str] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)

    def expect(self, condition: bool, what: str) -> bool:
        """Record ``what`` as a problem unless ``condition`` holds."""
        if not condition:
            self.problems.append(what)
        return bool(condition)

    @property
    def ok(self) -> bool:
        return not (self.crash or self.traceback or self.lost or self.problems)


@dataclass
class Run:
    """A finished command: exit code (None: killed after the timeout), output, crash."""

    code: int | None
    out: str
    err: str
    crashed: bool = False

    @property
    def traceback(self) -> bool:
        return TRACEBACK in self.out or TRACEBACK in self.err

    def line(self, limit: int = 170) -> str:
        """The first error line of stderr (else its first line saying what was skipped,
        else its first line, else stdout's), shortened."""
        for text in (self.err, self.out):
            lines = [line.strip() for line in text.splitlines() if line.strip()]
            for line in lines:
                if "error" in line.lower() or "refused" in line or "failure" in line:
                    return short(line, limit)
            skipped = self.skipped(limit)
            if skipped:
                return skipped
            if lines:
                return short(lines[0], limit)
        return ""

    def skipped(self, limit: int = 170) -> str:
        """The first line of stderr saying what was skipped (a bag, a duplicate), shortened;
        "" when none does."""
        for line in self.err.splitlines():
            if re.search(r"\bskipped (bag|duplicate|\d+)", line):
                return short(line, limit)
        return ""


#: Scratch directories shown in the table as ``.../`` (set by the Lab).
_SCRATCH: list[str] = []


def short(text: str, limit: int = 170) -> str:
    """One line, scratch paths elided, at most ``limit`` characters."""
    text = " ".join(str(text).split())
    text = re.sub(r"\[(ERROR|WARN|INFO)\] \[[\d.]+\] ", "", text)  # rcutils log prefixes
    text = text.replace("policy-align learn: ", "")
    for scratch in _SCRATCH:
        text = text.replace(scratch + "/", ".../")
    text = re.sub(r"\.\.\./\d{3}_", ".../", text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# --- the lab: scratch space, domain ids, how to run things -------------------------------
class Lab:
    """Scratch directory, DDS domain ids and the way CLI commands are run."""

    def __init__(self, workdir: Path, domain_base: int = 60, domain_count: int = 40,
                 cli_subprocess: bool = True, start_ups: bool = True, n_good: int = 8,
                 samples: int = 40) -> None:
        self.workdir = Path(workdir)
        _SCRATCH.append(str(self.workdir))
        self.domain_base, self.domain_count = domain_base, domain_count
        self._next_domain = 0
        self._next_dir = 0
        self.cli_subprocess = cli_subprocess
        #: Whether to run the node start-up cases (a process each, seconds per robot load).
        self.start_ups = start_ups
        #: Size of the good dataset: demonstrations, and samples in each.
        self.n_good, self.samples = n_good, samples
        self._good: Path | None = None

    def path(self, name: str) -> Path:
        """A fresh, empty directory under the work directory."""
        self._next_dir += 1
        path = self.workdir / f"{self._next_dir:03d}_{name}"
        path.mkdir(parents=True)
        return path

    def domain(self) -> int:
        """The next DDS domain id of this lab (cycling through its range)."""
        domain = self.domain_base + self._next_domain % self.domain_count
        self._next_domain += 1
        return domain

    def env(self, domain: int | None = None) -> dict[str, str]:
        env = dict(os.environ, PYTHONUNBUFFERED="1",
                   ROS_HOME=str(self.workdir / "ros_home"))
        if domain is not None:
            env["ROS_DOMAIN_ID"] = str(domain)
        return env

    def good_dataset(self) -> Path:
        """A dataset of ``n_good`` good 2-joint demonstrations (written once, then copied)."""
        if self._good is None:
            self._good = self.path("good")
            write_good_dataset(self._good, self.n_good, samples=self.samples)
        return self._good

    def dataset_with(self, name: str, n_good: int | None = None) -> Path:
        """A copy of the good dataset (its first ``n_good`` bags) in a fresh directory."""
        target = self.path(name)
        for bag in sorted(self.good_dataset().iterdir())[:n_good or self.n_good]:
            shutil.copytree(bag, target / bag.name)
        return target

    def cli(self, *argv: str, domain: int | None = None, timeout: float = 120.0) -> Run:
        """``policy-align ARGV`` as a subprocess, or through ``cli.main`` in-process."""
        if self.cli_subprocess:
            return run_process([str(BIN / "policy-align"), *argv], self.env(domain), timeout)
        return _cli_in_process(list(argv), domain)


def run_process(argv: Sequence[str], env: dict[str, str], timeout: float) -> Run:
    """Run ``argv``; a process still alive after ``timeout`` s is killed (code None)."""
    proc = subprocess.Popen(list(argv), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        return Run(None, out, err)
    return Run(proc.returncode, out, err, crashed=proc.returncode < 0)


def _cli_in_process(argv: list[str], domain: int | None) -> Run:
    from policy_align_ros import cli

    out, err = io.StringIO(), io.StringIO()
    crashed = False
    saved = os.environ.get("ROS_DOMAIN_ID")
    if domain is not None:
        os.environ["ROS_DOMAIN_ID"] = str(domain)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(argv)
            except SystemExit as exc:  # argparse usage errors
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            except BaseException:  # noqa: BLE001 - this is what the table counts as a crash
                traceback.print_exc()
                code, crashed = None, True
    finally:
        if saved is None:
            os.environ.pop("ROS_DOMAIN_ID", None)
        else:
            os.environ["ROS_DOMAIN_ID"] = saved
    return Run(code, out.getvalue(), err.getvalue(), crashed)



# --- datasets ---------------------------------------------------------------------------
def write_good_dataset(directory: Path, n_demos: int, seed: int = 0, samples: int = 40
                       ) -> list[Path]:
    """2-D demonstrations of pi = -x under a random line constraint each (dt 0.05 s)."""
    from policy_align_ros.data.bags.write import write_joint_state_bag

    rng = np.random.default_rng(seed)
    written = []
    for k in range(n_demos):
        alpha = rng.normal(size=2)
        projector = np.eye(2) - np.outer(alpha, alpha) / (alpha @ alpha)
        x = rng.uniform(-2.0, 2.0, 2)
        states = []
        for _ in range(samples):
            states.append(x.copy())
            x = x + 0.05 * (projector @ -x)
        stamps = T0 + k * 10**10 + np.arange(samples) * 50 * MS
        written.append(write_joint_state_bag(directory / f"demo_{k:04d}", J2, stamps,
                                             np.array(states)))
    return written

