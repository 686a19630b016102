#!/usr/bin/env python3
"""Robustness table of issue 8: bad inputs against the CLI, bags, parameters, messages, services.

Every case builds its bad input, feeds it to the package the way a user would (the
``policy-align`` command, a rosbag2 dataset, a parameter set through the node's
``set_parameters`` service, a message on the node's topic, a service call), observes what the
package did and checks it against what a robot owner expects. Nothing here decides a pass on
wall-clock speed: waits poll a condition and only bound a failure.

Columns of the table (``--markdown``):

* *crash*: the process died from an uncaught exception or a signal, a node callback raised,
  a service never answered, or a node stopped answering;
* *traceback*: ``Traceback (most recent call last)`` appeared in the output;
* *demos lost*: recorded messages missing from the bags on disk (recorder), or good
  demonstrations silently left out of a model that was written (bags); ``-`` when no
  demonstration is involved;
* *verdict*: ``ok``, or what differs from what a robot owner expects.

Usage::

    python tools/robustness.py                      # run everything, print the table
    python tools/robustness.py --markdown docs/robustness.md
    python tools/robustness.py --only cli,bags      # groups (cli = cli-learn, cli-misc, ...)
    python tools/robustness.py --in-process         # CLI cases through cli.main (faster)

ROS cases run in-process, each rig with its own ``rclpy.Context`` on its own DDS domain
(``--domain-base``, default 60: ids 60-99; test/test_robustness.py uses 204-216); node
start-up cases and, by default, CLI cases run as subprocesses of this interpreter's
environment.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from policy_align_ros.polling import wait_for

# The console scripts of this interpreter's environment (the venv), else those on PATH.
BIN = Path(sys.executable).parent
if not (BIN / "policy-align").exists() and shutil.which("policy-align"):
    BIN = Path(shutil.which("policy-align")).parent
TRACEBACK = "Traceback (most recent call last)"
AREAS = ("cli", "bags", "parameters", "messages", "services")
J2 = ["j1", "j2"]
T0 = 1_700_000_000 * 10**9
MS = 10**6


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
        """The first error line of stderr (else its first line, else stdout's), shortened."""
        for text in (self.err, self.out):
            lines = [line.strip() for line in text.splitlines() if line.strip()]
            for line in lines:
                if "error" in line.lower() or "refused" in line or "failure" in line:
                    return _short(line, limit)
            if lines:
                return _short(lines[0], limit)
        return ""


#: Scratch directories shown in the table as ``.../`` (set by the Lab).
_SCRATCH: list[str] = []


def _short(text: str, limit: int = 170) -> str:
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


# --- bags -------------------------------------------------------------------------------
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


def write_raw_bag(path: Path, messages: Sequence[tuple], *, storage: str = "mcap",
                  topic: str = "/joint_states", msgtype: str = "sensor_msgs/msg/JointState"
                  ) -> Path:
    """A bag of arbitrary messages, as another tool could write it.

    ``messages`` are ``(stamp_ns, names, positions, velocities)`` for JointState, or
    ``(stamp_ns, text)`` for ``std_msgs/msg/String``. The bag (receive) times increase by
    1 ms a message from the first stamp whatever the header stamps do, as in a recording.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8 if storage != "mcap" else 9, storage_plugin=plugin) as writer:
        conn = writer.add_connection(topic, msgtype, typestore=store)
        cls = store.types[msgtype]
        received = int(messages[0][0]) if messages else T0
        for k, item in enumerate(messages):
            stamp = int(item[0])
            if msgtype.endswith("String"):
                msg = cls(data=item[1])
            else:
                header = store.types["std_msgs/msg/Header"](
                    stamp=store.types["builtin_interfaces/msg/Time"](
                        sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="")
                msg = cls(header=header, name=list(item[1]),
                          position=np.asarray(item[2], dtype=float),
                          velocity=np.asarray(item[3], dtype=float), effort=np.empty(0))
            writer.write(conn, received + k * MS, store.serialize_cdr(msg, msgtype))
    return path


def _good_messages(n: int = 40, start: int = T0 + 10**12) -> list[tuple]:
    return [(start + k * 50 * MS, J2, [0.5 - 0.01 * k, -0.3 + 0.005 * k], [])
            for k in range(n)]


def _learn_outcome(r: Result, run: Run, model: Path, good_bags: Sequence[str]) -> None:
    """Fill crash/traceback, and count the good bags silently left out of a written model.

    A bag reached the fit when the written model's training summary names it (used, held
    out or discarded as an outlier or duplicate are all decisions about it). A refused
    ``learn`` (no model, a reason on stderr) loses nothing: the bags stay on disk, and the
    verdict says whether refusing was right. ``lost`` stays None for a header that names
    no bag.
    """
    r.crash, r.traceback = run.crashed, run.traceback
    r.data.update(code=run.code, err=run.err, out=run.out)
    if run.code != 0 or not model.is_file():
        r.lost = 0
        return
    with np.load(model, allow_pickle=False) as data:
        header = json.loads(str(data["__header__"]))
    text = json.dumps(header.get("training", {}))
    named = [b for b in good_bags if b in text]
    r.lost = len(good_bags) - len(named) if named else None
    r.data["header"] = header


# --- ROS rigs ---------------------------------------------------------------------------
class NodeRig:
    """A node under test and a probe node, spun in the background on their own domain.

    Callback exceptions are caught per spin, recorded in ``errors`` (they count as crashes)
    and spinning goes on, so one case's crash does not hide the next case's behaviour.
    """

    def __init__(self, lab: Lab, make: Callable[..., Any], params: dict[str, Any] | None = None,
                 threads: int = 3) -> None:
        import rclpy
        from rclpy.executors import MultiThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter

        self.domain = lab.domain()
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=self.domain)
        self.errors: list[str] = []
        try:
            self.node = make(context=self.context, parameter_overrides=[
                Parameter(k, value=v) for k, v in (params or {}).items()])
        except BaseException:
            rclpy.try_shutdown(context=self.context)
            raise
        self.name = self.node.get_fully_qualified_name()
        self.probe = Node("robustness_probe", context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=threads, context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()
        self._clients: dict[tuple[Any, str], Any] = {}
        self._publishers: dict[tuple[Any, str], Any] = {}

    def _spin(self) -> None:
        # spin(), not a loop of spin_once(): MultiThreadedExecutor.spin_once can leave a
        # reentrant service unanswered after concurrent calls.
        while not self._stop.is_set() and self.context.ok():
            try:
                self.executor.spin()
            except Exception:  # noqa: BLE001 - recorded as a crash of the node under test
                self.errors.append(traceback.format_exc())

    def call(self, srv_type: Any, service: str, request: Any = None,
             timeout: float = 30.0) -> Any:
        """Call a service from the probe; the response, or None if none came in time."""
        client = self.client(srv_type, service)
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        future = client.call_async(request if request is not None else srv_type.Request())
        wait_for(future.done, timeout)
        return future.result() if future.done() else None

    def client(self, srv_type: Any, service: str) -> Any:
        """The probe's one client of ``service`` (one per service: a second client of the
        same service in the same node can miss its responses)."""
        key = (srv_type, service)
        client = self._clients.get(key)
        if client is None:
            client = self._clients[key] = self.probe.create_client(srv_type, service)
        return client

    def set_param(self, name: str, value: Any) -> tuple[bool, str]:
        """Set a parameter through the node's ``set_parameters`` service (as a user does)."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()])
        response = self.call(SetParameters, f"{self.name}/set_parameters", request)
        if response is None:
            return False, "NO ANSWER"
        result = response.results[0]
        return bool(result.successful), result.reason

    def publish(self, msg_type: Any, topic: str, msg: Any) -> None:
        key = (msg_type, topic)
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = self.probe.create_publisher(msg_type, topic, 100)
        pub.publish(msg)

    def alive(self) -> bool:
        """The node still answers a parameter request."""
        from rcl_interfaces.srv import ListParameters

        return self.call(ListParameters, f"{self.name}/list_parameters",
                         timeout=10.0) is not None

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self.executor.shutdown()
        self._thread.join(timeout=5.0)
        self.probe.destroy_node()
        shutdown = getattr(self.node, "shutdown", None)
        if callable(shutdown):
            shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@contextlib.contextmanager
def rig_case(r: Result, rig: NodeRig) -> Iterator[None]:
    """Count callback exceptions raised during the block, and a node that stops answering."""
    before = len(rig.errors)
    yield
    new = rig.errors[before:]
    if new:
        r.crash = r.traceback = True
        r.data["errors"] = new
    elif not rig.alive():
        r.crash = True
        r.problems.append("the node stopped answering")


def node_start(lab: Lab, executable: str, *ros_args: str, timeout: float = 60.0) -> Run:
    """Start a node executable with ``--ros-args ROS_ARGS``; it should exit by itself."""
    return run_process([str(BIN / executable), "--ros-args", *ros_args],
                       lab.env(lab.domain()), timeout)


def _start_refused(r: Result, run: Run, *needles: str) -> None:
    r.crash, r.traceback = run.crashed, run.traceback
    r.data.update(code=run.code, err=run.err)
    if run.code is None:
        r.behaviour = "started and kept running with the bad value"
        r.problems.append("a bad start-up parameter was accepted")
        return
    r.behaviour = f"exit {run.code}: {run.line()}"
    r.expect(run.code != 0, "exit status 0")
    text = run.err + run.out
    for needle in needles:
        r.expect(needle in text, f"the reason does not mention {needle!r}")


# --- CLI ---------------------------------------------------------------------------------
def _cli_result(case: str, tried: str, run: Run, code: int | None, *needles: str,
                area: str = "cli") -> Result:
    r = Result(case, area, tried, crash=run.crashed, traceback=run.traceback)
    r.behaviour = f"exit {run.code}: {run.line()}" if run.code is not None else \
        "did not finish within the timeout (killed)"
    r.data.update(code=run.code, out=run.out, err=run.err)
    if code is not None:
        r.expect(run.code == code, f"exit status {run.code}, expected {code}")
    text = run.out + run.err
    for needle in needles:
        r.expect(needle in text, f"the message does not mention {needle!r}")
    return r


def cases_cli_learn(lab: Lab) -> list[Result]:
    """``policy-align learn`` with unusable paths and options."""
    out = []
    work = lab.path("cli_learn")
    good = lab.good_dataset()
    model = str(work / "model.npz")
    (work / "empty").mkdir()
    (work / "notes.txt").write_text("not a bag\n")
    (work / "a_file").write_text("x")
    (work / "a_dir").mkdir()

    def learn(case, tried, argv, code, *needles):
        out.append(_cli_result(case, tried, lab.cli("learn", *argv), code, *needles))
        return out[-1]

    learn("learn-missing-path", "`learn /nonexistent/demos --out m.npz`",
          [str(work / "nonexistent" / "demos"), "--out", model], 2, "nonexistent")
    learn("learn-empty-dir", "`learn EMPTY_DIR --out m.npz`",
          [str(work / "empty"), "--out", model], 2, "empty")
    learn("learn-not-a-bag", "`learn notes.txt --out m.npz` (a text file)",
          [str(work / "notes.txt"), "--out", model], 2, "notes.txt")
    learn("learn-sigma-negative", "`learn GOOD --sigma -1`",
          [str(good), "--out", model, "--sigma", "-1"], 2, "sigma")
    learn("learn-sigma-nan", "`learn GOOD --sigma nan`",
          [str(good), "--out", model, "--sigma", "nan"], 2, "sigma")
    learn("learn-sigma-word", "`learn GOOD --sigma huge`",
          [str(good), "--out", model, "--sigma", "huge"], 2, "sigma")
    learn("learn-joints-empty-name", "`learn GOOD --joints j1,,j2`",
          [str(good), "--out", model, "--joints", "j1,,j2"], 2, "joints")
    learn("learn-joints-repeated", "`learn GOOD --joints j1,j1`",
          [str(good), "--out", model, "--joints", "j1,j1"], 2, "j1")
    learn("learn-joints-unknown", "`learn GOOD --joints j1,not_a_joint` (bags have j1, j2)",
          [str(good), "--out", model, "--joints", "j1,not_a_joint"], 2, "not_a_joint", "j2")
    learn("learn-gap-nan", "`learn GOOD --gap nan`",
          [str(good), "--out", model, "--gap", "nan"], 2, "gap")
    learn("learn-out-under-file", "`learn GOOD --out A_FILE/model.npz` (parent is a file)",
          [str(good), "--out", str(work / "a_file" / "model.npz")], 2, "a_file")
    learn("learn-out-is-dir", "`learn GOOD --out A_DIR` (an existing directory)",
          [str(good), "--out", str(work / "a_dir")], 2, "a_dir")
    learn("learn-state-unknown-kind", "`learn GOOD --state velocities`",
          [str(good), "--out", model, "--state", "velocities"], 2, "state")
    learn("learn-state-empty-frames", "`learn GOOD --state frames:`",
          [str(good), "--out", model, "--state", "frames:"], 2, "frame")
    learn("learn-state-frames-no-robot", "`learn GOOD --state frames:arm_left_7_link` "
          "(no `--robot`)", [str(good), "--out", model, "--state", "frames:arm_left_7_link"],
          2, "robot")
    learn("learn-state-unknown-frame", "`learn GOOD --robot talos --state frames:no_frame`",
          [str(good), "--out", model, "--robot", "talos", "--state", "frames:no_frame"], 2)
    one = lab.dataset_with("one_demo", n_good=1)
    learn("learn-one-demo", "`learn ONE_BAG_DATASET` (a single demonstration)",
          [str(one), "--out", model], 2, "2")
    r = learn("learn-same-dataset-twice", "`learn GOOD GOOD` (every bag given twice)",
              [str(good), str(good), "--out", str(work / "twice.npz")], None)
    r.expect(r.data["code"] in (0, 2), "exit status neither 0 nor 2")
    r.expect("duplicate" in (r.data["out"] + r.data["err"]).lower(),
             "the duplicates are not reported")
    dup = lab.dataset_with("dup_bags")
    for bag in sorted(dup.iterdir()):
        shutil.copytree(bag, dup / f"copy_of_{bag.name}")
    r = learn("learn-duplicated-bags", "`learn DATASET` where every bag has a copy",
              [str(dup), "--out", str(work / "dup.npz")], None)
    r.expect(r.data["code"] in (0, 2), "exit status neither 0 nor 2")
    r.expect("duplicate" in (r.data["out"] + r.data["err"]).lower(),
             "the duplicates are not reported")
    return out


def cases_cli_misc(lab: Lab) -> list[Result]:
    """``bench`` and the command itself with bad arguments."""
    out = []
    work = lab.path("cli_bench")
    out.append(_cli_result("no-command", "`policy-align` (no sub-command)", lab.cli(), 2))
    out.append(_cli_result("bench-unknown", "`bench nosuch`", lab.cli("bench", "nosuch"), 2,
                           "invalid choice"))
    out.append(_cli_result(
        "bench-jobs-zero", "`bench toy --jobs 0 --datasets 1`",
        lab.cli("bench", "toy", "--jobs", "0", "--datasets", "1", "--out", str(work / "a"),
                timeout=300), 2, "jobs"))
    out.append(_cli_result(
        "bench-datasets-negative", "`bench toy --datasets -1`",
        lab.cli("bench", "toy", "--datasets", "-1", "--out", str(work / "b"), timeout=300),
        2, "datasets"))
    out.append(_cli_result(
        "bench-set-malformed", "`bench suite --set offset_ridge` (no `=`)",
        lab.cli("bench", "suite", "--set", "offset_ridge", "--datasets", "1",
                "--out", str(work / "c"), timeout=300), 2, "offset_ridge"))
    return out


def cases_cli_ros(lab: Lab) -> list[Result]:
    """``call`` and ``param`` against a running recorder, and against nothing."""
    from policy_align_ros.nodes.recorder import RecorderNode

    out = []
    work = lab.path("cli_ros")
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(work / "demos")})
    d = rig.domain
    try:
        out.append(_cli_result("call-missing-service", "`call /no_such_service --timeout 2`",
                               lab.cli("call", "/no_such_service", "--timeout", "2",
                                       domain=d), 3, "not available"))
        out.append(_cli_result(
            "call-wrong-type", "`call /recorder/start_demo --data true` (a Trigger)",
            lab.cli("call", "/recorder/start_demo", "--data", "true", domain=d), 2,
            "omit --data"))
        out.append(_cli_result(
            "call-unsupported-type", "`call /recorder/get_parameters` (not Trigger/SetBool)",
            lab.cli("call", "/recorder/get_parameters", "--timeout", "10", domain=d), 2,
            "GetParameters"))
        out.append(_cli_result("call-timeout-zero", "`call /recorder/stop_demo --timeout 0`",
                               lab.cli("call", "/recorder/stop_demo", "--timeout", "0",
                                       domain=d), 2, "timeout"))
        out.append(_cli_result(
            "param-missing-node", "`param get /no_such_node rate_hz --timeout 2`",
            lab.cli("param", "get", "/no_such_node", "rate_hz", "--timeout", "2", domain=d),
            3, "no_such_node"))
        out.append(_cli_result("param-unknown-name", "`param get /recorder no_such_param`",
                               lab.cli("param", "get", "/recorder", "no_such_param",
                                       domain=d), 2, "no_such_param"))
        out.append(_cli_result(
            "param-bad-value-type", "`param set /recorder auto_split_gap_s fast`",
            lab.cli("param", "set", "/recorder", "auto_split_gap_s", "fast", domain=d), 2,
            "double"))
        out.append(_cli_result(
            "param-refused-value", "`param set /recorder auto_split_gap_s -1`",
            lab.cli("param", "set", "/recorder", "auto_split_gap_s", "-1", domain=d), 1,
            "refused"))
        out.append(_cli_result(
            "param-read-only", "`param set /recorder qos_depth 5` (read-only)",
            lab.cli("param", "set", "/recorder", "qos_depth", "5", domain=d), 1, "read-only"))
        out.append(_cli_result(
            "call-invalid-name", "`call '/no such service'` (not a valid name)",
            lab.cli("call", "/no such service", "--timeout", "2", domain=d), 2, "valid"))
        out.append(_cli_result(
            "param-invalid-node-name", "`param get 'no such node' rate_hz` (not a valid name)",
            lab.cli("param", "get", "no such node", "rate_hz", "--timeout", "2", domain=d),
            2, "not a valid node name"))
        out.append(_cli_result(
            "param-array-bad-yaml", "`param set /recorder joints '[j1, j2'` (unclosed YAML)",
            lab.cli("param", "set", "/recorder", "joints", "[j1, j2", domain=d), 2, "YAML"))
        out.append(_cli_result(
            "param-unset-parameter", "`param set /recorder joints '[j1, j1]'` (declared, "
            "unset, repeated joint)",
            lab.cli("param", "set", "/recorder", "joints", "[j1, j1]", domain=d), 1,
            "listed twice"))
        out.append(_cli_result("param-set-no-value", "`param set /recorder dataset_dir`",
                               lab.cli("param", "set", "/recorder", "dataset_dir", domain=d),
                               2, "VALUE"))
        r = out[-1]
        r.expect(rig.alive() and not rig.errors, "the recorder did not survive the calls")
    finally:
        rig.close()
    return out


def cases_cli_demo(lab: Lab) -> list[Result]:
    """``policy-align demo`` with arguments it cannot use (it must stop before the graph)."""
    work = lab.path("cli_demo")
    (work / "a_file").write_text("x")
    d = lab.domain()
    return [
        _cli_result("demo-unknown-robot", "`demo --robot no_such_robot`",
                    lab.cli("demo", "--robot", "no_such_robot", "--out", str(work / "a"),
                            domain=d, timeout=300), 2, "no_such_robot"),
        _cli_result("demo-out-under-file", "`demo --out A_FILE/out` (parent is a file)",
                    lab.cli("demo", "--out", str(work / "a_file" / "out"), domain=d,
                            timeout=300), 2, "a_file"),
        _cli_result("demo-seed-negative", "`demo --seed -1`",
                    lab.cli("demo", "--seed", "-1", "--out", str(work / "b"), domain=d,
                            timeout=300), 2, "seed"),
    ]


# --- bag cases -------------------------------------------------------------------------------
def _bag_case(lab: Lab, case: str, tried: str, make_bad: Callable[[Path], Path],
              alone_code: int | None = 2, alone: bool = True, extra: Sequence[str] = ()
              ) -> Result:
    """A bad bag inside the good dataset (``learn DATASET``), and on its own.

    Beside good bags the fit must go ahead with every good demonstration and name the bad
    bag (``alone=False``: a valid bag, which must simply be used); alone, ``learn`` must
    stop with ``alone_code`` and a message naming the bag.
    """
    dataset = lab.dataset_with(case)
    good = sorted(p.name for p in dataset.iterdir())
    bad = make_bad(dataset)
    model = dataset.parent / f"{case}.npz"
    run = lab.cli("learn", str(dataset), "--out", str(model), *extra)
    r = Result(case, "bags", tried)
    _learn_outcome(r, run, model, good)
    n = len(good)
    r.expect(run.code == 0, f"with {n} good bags beside it: exit {run.code} ({run.line()})")
    if run.code == 0:
        used = "?" if r.lost is None else str(len(good) - r.lost)
        note = (_short(run.err.strip().splitlines()[0], 130) if run.err.strip()
                else "nothing reported")
        r.behaviour = f"beside {n} good bags: exit 0, {used}/{n} good demos used; {note}"
        if alone:
            r.expect(bad.name in run.err + run.out, "beside good bags it is not named")
    else:
        r.behaviour = f"beside {n} good bags: exit {run.code}: {run.line(150)}"
    if alone:
        solo = lab.path(f"{case}_alone")
        target = solo / bad.name
        (shutil.copytree if bad.is_dir() else shutil.copy)(bad, target)
        run2 = lab.cli("learn", str(target), "--out", str(solo / "m.npz"))
        r.crash |= run2.crashed
        r.traceback |= run2.traceback
        r.data["alone"] = {"code": run2.code, "err": run2.err, "out": run2.out}
        r.behaviour += f". Alone: exit {run2.code}: {run2.line(130)}"
        if alone_code is not None:
            r.expect(run2.code == alone_code, f"alone: exit {run2.code}, expected {alone_code}")
            r.expect(bad.name in run2.out + run2.err, "alone: the message does not name the bag")
    return r


def cases_bags(lab: Lab) -> list[Result]:
    """Bags that are malformed, foreign or broken, each beside good ones and alone."""
    out = []
    start = T0 + 10**12

    def raw(name, messages, **kw):
        return lambda d: write_raw_bag(d / name, messages, **kw)

    out.append(_bag_case(lab, "bag-lengths-disagree",
                         "a bag whose messages have 2 names and 1 position",
                         raw("bad_lengths", [(start + k * 50 * MS, J2, [0.1], [])
                                             for k in range(20)])))
    out.append(_bag_case(lab, "bag-non-finite", "a bag of NaN and inf positions",
                         raw("bad_nan", [(start + k * 50 * MS, J2,
                                          [np.nan if k % 2 else np.inf, 0.0], [])
                                         for k in range(20)])))
    out.append(_bag_case(lab, "bag-duplicate-joint", "a bag whose messages name j1 twice",
                         raw("bad_dup", [(start + k * 50 * MS, ["j1", "j1"], [0.1, 0.2], [])
                                         for k in range(20)])))
    out.append(_bag_case(lab, "bag-time-backwards", "a bag whose stamps go backwards",
                         raw("bad_backwards", [(start - k * 50 * MS, J2, [0.1, 0.2], [])
                                               for k in range(20)])))
    out.append(_bag_case(lab, "bag-unknown-joints", "a bag of other joints (x1, x2)",
                         raw("bad_foreign", [(start + k * 50 * MS, ["x1", "x2"], [0.1, 0.2],
                                              []) for k in range(20)])))
    out.append(_bag_case(lab, "bag-unknown-joints-selected",
                         "the same bag of x1, x2 with `learn DATASET --joints j1,j2`",
                         raw("bad_foreign", [(start + k * 50 * MS, ["x1", "x2"], [0.1, 0.2],
                                              []) for k in range(20)]),
                         alone=False, extra=("--joints", "j1,j2")))
    out[-1].expect("bad_foreign" in out[-1].data["err"] + out[-1].data["out"],
                   "beside good bags it is not named")
    out.append(_bag_case(lab, "bag-sqlite3", "a valid sqlite3 (.db3) bag (Humble's default)",
                         raw("humble_bag", _good_messages(), storage="sqlite3"),
                         alone=False))
    out.append(_bag_case(lab, "bag-no-joint-state", "a bag with only a std_msgs/String topic",
                         raw("bad_chatter", [(start + k * MS, "hello") for k in range(5)],
                             topic="/chatter", msgtype="std_msgs/msg/String")))

    def zero_byte(d):
        (d / "empty.mcap").write_bytes(b"")
        return d / "empty.mcap"

    out.append(_bag_case(lab, "bag-zero-byte-mcap", "a zero-byte `empty.mcap`", zero_byte))

    def nowhere(d):
        bag = d / "bad_nowhere"
        shutil.copytree(d / "demo_0000", bag)
        for f in bag.glob("*.mcap"):
            f.unlink()
        return bag

    out.append(_bag_case(lab, "bag-metadata-nowhere",
                         "a bag directory whose metadata.yaml names a missing .mcap", nowhere))

    def garbage(d):
        bag = d / "bad_metadata"
        bag.mkdir()
        (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {{{ [not yaml\n")
        return bag

    out.append(_bag_case(lab, "bag-metadata-garbage", "a metadata.yaml that is not YAML",
                         garbage))

    def truncated(d):
        bag = d / "bad_truncated"
        shutil.copytree(d / "demo_0001", bag)
        for f in bag.glob("*.mcap"):
            data = f.read_bytes()
            f.write_bytes(data[: len(data) // 2])
        return bag

    out.append(_bag_case(lab, "bag-truncated", "a bag whose .mcap is cut in half", truncated))

    def no_metadata(d):
        bag = d / "bad_no_metadata"
        shutil.copytree(d / "demo_0002", bag)
        (bag / "metadata.yaml").unlink()
        return bag

    out.append(_bag_case(lab, "bag-no-metadata", "a bag directory with its .mcap but no "
                         "metadata.yaml (as `ros2 bag record` leaves when killed)",
                         no_metadata, alone_code=None))

    def no_footer(d):
        bag = no_metadata(d).rename(d / "bad_no_footer")
        for f in bag.glob("*.mcap"):
            data, pos = f.read_bytes(), 8
            while data[pos] != 0x0F:  # walk the records to the Data End record
                pos += 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
            f.write_bytes(data[:pos] + b"\x06\x40")  # and a record cut short
        return bag

    out.append(_bag_case(lab, "bag-killed-no-footer", "the same, its .mcap ending in a "
                         "half-written record, with no summary and no footer (`ros2 bag "
                         "record` killed with SIGKILL)", no_footer, alone_code=None))

    def unfinished(d):
        bag = d / ".tmp-demo_0100"
        shutil.copytree(d / "demo_0003", bag)
        for f in bag.glob("*.mcap"):
            f.write_bytes(f.read_bytes()[:100])
        return bag

    r = _bag_case(lab, "bag-unfinished-hidden", "a hidden `.tmp-demo_0100` bag (a recorder "
                  "killed mid-write)", unfinished, alone=False)
    out.append(r)
    return out


# --- recorder: parameters, messages, services --------------------------------------------
def _param_case(rig: NodeRig, case: str, tried: str, name: str, value: Any,
                *needles: str) -> Result:
    """Set a bad value at run time: it must be refused with a reason, the node unharmed."""
    r = Result(case, "parameters", tried)
    with rig_case(r, rig):
        before = _get_param(rig, name)
        ok, reason = rig.set_param(name, value)
        after = _get_param(rig, name)
    r.data.update(successful=ok, reason=reason)
    r.behaviour = "accepted" if ok else f"refused: {_short(reason, 150)}"
    r.expect(not ok, "the bad value was accepted")
    r.expect(bool(reason.strip()) or ok, "refused without a reason")
    for needle in needles:
        r.expect(needle in reason, f"the reason does not mention {needle!r}")
    r.expect(ok or _same(before, after), "the value changed although refused")
    return r


def _get_param(rig: NodeRig, name: str) -> Any:
    try:
        return rig.node.get_parameter(name).value
    except Exception:  # noqa: BLE001 - an unset parameter
        return None


def _same(a: Any, b: Any) -> bool:
    try:
        return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))
    except TypeError:
        return a == b


def _trigger(rig: NodeRig, service: str) -> Any:
    from std_srvs.srv import Trigger

    return rig.call(Trigger, service, Trigger.Request())


def _service_case(rig: NodeRig, case: str, tried: str, call: Callable[[], Any],
                  success: bool, *needles: str) -> Result:
    r = Result(case, "services", tried)
    with rig_case(r, rig):
        response = call()
    if response is None:
        # An answer that never comes is what a service callback that raised looks like.
        r.behaviour = "no answer within 30 s"
        r.crash = True
        r.problems.append("the service did not answer")
        return r
    r.data.update(success=response.success, message=response.message)
    r.behaviour = f"success={str(response.success).lower()}: {_short(response.message, 150)}"
    r.expect(response.success == success, f"success={response.success}, expected {success}")
    for needle in needles:
        r.expect(needle in response.message, f"the message does not mention {needle!r}")
    return r


def cases_recorder(lab: Lab) -> list[Result]:
    """The recorder: bad parameters, malformed joint states, services out of order."""
    from sensor_msgs.msg import JointState

    from policy_align_ros.data.bags.dataset import load_dataset
    from policy_align_ros.nodes.recorder import RecorderNode

    out: list[Result] = []
    work = lab.path("recorder")
    (work / "a_file").write_text("x")
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(work / "demos"), "joints": J2})
    try:
        rec = rig.node.recorder
        p = _param_case
        out.append(p(rig, "rec-dataset-dir-under-file",
                     "recorder `dataset_dir` set at run time to a path under a file",
                     "dataset_dir", str(work / "a_file" / "demos"), "dataset_dir"))
        out.append(p(rig, "rec-dataset-dir-empty", "recorder `dataset_dir: ''`",
                     "dataset_dir", "", "dataset_dir"))
        out.append(p(rig, "rec-joints-repeated", "recorder `joints: [j1, j1]`",
                     "joints", ["j1", "j1"], "j1"))
        out.append(p(rig, "rec-joints-empty-name", "recorder `joints: [j1, '']`",
                     "joints", ["j1", ""], "joint"))
        out.append(p(rig, "rec-gap-nan", "recorder `auto_split_gap_s: nan`",
                     "auto_split_gap_s", float("nan")))
        out.append(p(rig, "rec-gap-negative", "recorder `auto_split_gap_s: -1.0`",
                     "auto_split_gap_s", -1.0))
        out.append(p(rig, "rec-gap-wrong-type", "recorder `auto_split_gap_s: 'fast'` (string)",
                     "auto_split_gap_s", "fast"))
        out.append(p(rig, "rec-qos-depth-read-only", "recorder `qos_depth: 5` at run time",
                     "qos_depth", 5))
        out.append(p(rig, "rec-warn-period-zero", "recorder `warn_period_s: 0.0`",
                     "warn_period_s", 0.0))

        s = _service_case
        out.append(s(rig, "rec-stop-without-start", "recorder `~/stop_demo` with no start",
                     lambda: _trigger(rig, "/recorder/stop_demo"), False))
        first = _trigger(rig, "/recorder/start_demo")
        out.append(s(rig, "rec-start-twice", "recorder `~/start_demo` twice in a row",
                     lambda: _trigger(rig, "/recorder/start_demo"), False, "already"))
        out[-1].expect(first is not None and first.success, "the first start_demo failed")

        def state(names, pos, vel=(), stamp=None):
            msg = JointState(name=list(names), position=[float(v) for v in pos],
                             velocity=[float(v) for v in vel])
            msg.header.stamp = (rig.node.get_clock().now().to_msg() if stamp is None
                                else stamp)
            return msg

        good_sent = 0

        def send_good(n=2):
            nonlocal good_sent
            for _ in range(n):
                target = rec.accepted + 1
                rig.publish(JointState, "/joint_states",
                            state(J2, [0.1 * good_sent, 0.2]))
                good_sent += 1
                wait_for(lambda t=target: rec.accepted >= t, 10.0)

        def msg_case(case, tried, make_msg, reason):
            send_good()
            r = Result(case, "messages", tried)
            with rig_case(r, rig):
                skipped, accepted = sum(rec.skipped.values()), rec.accepted
                # Built now: a stamp taken before the good messages would be "backwards".
                rig.publish(JointState, "/joint_states", make_msg())
                if reason is None:
                    wait_for(lambda: rec.accepted > accepted, 10.0)
                else:
                    wait_for(lambda: rec.skipped[reason] > 0 and
                             sum(rec.skipped.values()) > skipped, 10.0)
                send_good(1)  # the stream goes on after the bad message
            new_skips = {k: v for k, v in rec.skipped.items() if v} if reason else {}
            if reason is None:
                r.expect(rec.accepted >= accepted + 2, "a valid message was not recorded")
            else:
                r.behaviour = f"skipped and counted as `{reason}` ({rec.skipped[reason]})"
                r.expect(sum(rec.skipped.values()) == skipped + 1,
                         f"not skipped as {reason}: {new_skips}")
                r.expect(rec.accepted == accepted + 1,
                         "the valid message after it was not recorded")
            r.data["skipped"] = dict(rec.skipped)
            out.append(r)
            return r

        now = rig.node.get_clock().now
        msg_case("rec-msg-missing-joint", "JointState with j1 only (recorder selects j1, j2)",
                 lambda: state(["j1"], [0.1]), "missing_joints")
        r = msg_case("rec-msg-extra-joint", "JointState with an extra joint j3",
                     lambda: state(["j3", "j2", "j1"], [9.0, 0.2, 0.1]), None)
        r.behaviour = "recorded: j1, j2 matched by name, j3 ignored"
        msg_case("rec-msg-empty", "JointState with empty name/position arrays",
                 lambda: state([], []), "unknown_joints")
        msg_case("rec-msg-lengths", "JointState with 2 names and 1 position",
                 lambda: state(J2, [0.1]), "length_mismatch")
        msg_case("rec-msg-nan", "JointState with a NaN position", lambda: state(J2, [np.nan, 0.2]),
                 "non_finite")
        msg_case("rec-msg-inf-velocity", "JointState with an inf velocity",
                 lambda: state(J2, [0.1, 0.2], [np.inf, 0.0]), "non_finite")
        msg_case("rec-msg-joint-twice", "JointState naming j1 twice (other values)",
                 lambda: state(["j1", "j2", "j1"], [0.1, 0.2, 0.7]), "duplicate_joints")
        msg_case("rec-msg-stamp-backwards", "JointState stamped 5 s before the last one",
                 lambda: state(J2, [0.1, 0.2], stamp=(now() - _duration(5.0)).to_msg()),
                 "time_not_increasing")
        from builtin_interfaces.msg import Time

        r = msg_case("rec-msg-stamp-zero", "JointState with a zero header stamp",
                     lambda: state(J2, [0.1, 0.2], stamp=Time()), None)
        r.behaviour = "recorded, stamped with the node clock (unstamped message)"
        r = msg_case("rec-msg-stamp-future", "JointState stamped 1 h in the future",
                     lambda: state(J2, [0.1, 0.2], stamp=(now() + _duration(3600.0)).to_msg()),
                     "time_in_future")
        before = rec.accepted
        send_good(3)
        r.expect(rec.accepted == before + 3,
                 "valid messages after the future stamp are not recorded")
        msg_case("rec-msg-stamp-negative", "JointState stamped before the epoch (sec = -1)",
                 lambda: state(J2, [0.1, 0.2], stamp=Time(sec=-1)), "time_negative")
        out.append(p(rig, "rec-joints-while-recording",
                     "recorder `joints: [j2, j1]` while a demonstration is recorded",
                     "joints", ["j2", "j1"], "joints"))
        accepted = rec.accepted
        response = _trigger(rig, "/recorder/stop_demo")
        # Every valid message must be in the bag: the demonstrations lost.
        r = out[-1]
        ok = response is not None and response.success
        written = 0
        if ok:
            trajs, _, _ = load_dataset(response.message, gap_s=0.0)
            written = sum(len(t.positions) for t in trajs)
        for row in out:
            if row.area == "messages":
                row.lost = 0 if ok and written == accepted else 1
                row.data.update(written=written, accepted=accepted)
        out.append(s(rig, "rec-stop-nothing-valid",
                     "recorder `~/start_demo` then `~/stop_demo` with no valid message",
                     lambda: (_trigger(rig, "/recorder/start_demo"),
                              rig.publish(JointState, "/joint_states", state(["j1"], [0.0])),
                              time.sleep(0.2),
                              _trigger(rig, "/recorder/stop_demo"))[-1], False, "nothing"))
    finally:
        rig.close()
    out.extend(_recorder_write_failures(lab, work))
    if not lab.start_ups:
        return out
    # Start-up: a recorder that cannot write its dataset must not start.
    run = node_start(lab, "recorder", "-p", f"dataset_dir:={work / 'a_file' / 'demos'}")
    r = Result("rec-start-dir-under-file", "parameters",
               "`recorder --ros-args -p dataset_dir:=A_FILE/demos` (start-up)")
    _start_refused(r, run, "dataset_dir")
    out.append(r)
    run = node_start(lab, "recorder", "-p", f"dataset_dir:={work / 'ok'}",
                     "-p", "joints:=[j1, j1]")
    r = Result("rec-start-joints-repeated", "parameters",
               "`recorder --ros-args -p 'joints:=[j1, j1]'` (start-up)")
    _start_refused(r, run, "j1")
    out.append(r)
    return out


def _recorder_write_failures(lab: Lab, work: Path) -> list[Result]:
    """A dataset directory replaced by a file mid-demo; a clock that restarts while
    recording continuously. Nothing recorded may be lost."""
    from sensor_msgs.msg import JointState

    from policy_align_ros.data import find_bags, load_dataset
    from policy_align_ros.nodes.recorder import RecorderNode

    out = []

    def state(rig, k, offset_s=0.0):
        msg = JointState(name=J2, position=[0.01 * k, -0.01 * k])
        msg.header.stamp = (rig.node.get_clock().now() + _duration(offset_s)).to_msg()
        return msg

    def messages_in(directory):
        bags = find_bags(directory) if directory.is_dir() else []
        if not bags:
            return 0
        trajs, _, _ = load_dataset(directory, gap_s=0.0)
        return sum(len(t.positions) for t in trajs)

    demos = work / "replaced"
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(demos), "joints": J2})
    r = Result("rec-dataset-dir-replaced", "services",
               "recorder: `dataset_dir` replaced by a file during a demonstration, then "
               "`~/stop_demo`, `~/start_demo`, `dataset_dir` set to a new directory, "
               "`~/stop_demo`")
    try:
        rec = rig.node.recorder
        with rig_case(r, rig):
            _trigger(rig, "/recorder/start_demo")
            for k in range(10):
                rig.publish(JointState, "/joint_states", state(rig, k))
            wait_for(lambda: rec.accepted >= 10, 10.0)
            shutil.rmtree(demos)
            demos.write_text("in the way\n")
            stop = _trigger(rig, "/recorder/stop_demo")
            start = _trigger(rig, "/recorder/start_demo")
            moved = rig.set_param("dataset_dir", str(work / "moved"))
            again = _trigger(rig, "/recorder/stop_demo")
        answers = [stop, start, again]
        if r.expect(all(a is not None for a in answers), "a service did not answer"):
            r.behaviour = (f"stop: success={str(stop.success).lower()} "
                           f"({_short(stop.message, 150)}); start: "
                           f"success={str(start.success).lower()}; after the new "
                           f"dataset_dir, stop: success={str(again.success).lower()} "
                           "(the 10 messages written)")
            r.expect(not stop.success and "writing failed" in stop.message,
                     "the failed write was not reported")
            r.expect(not start.success and "could not be written" in start.message,
                     "start_demo not refused while a demonstration is pending")
            r.expect(moved[0] and again.success, "the pending demonstration was not written")
        written = messages_in(work / "moved")
        r.lost = 0 if written == 10 else 1
        r.data["written"] = written
    finally:
        rig.close()
    out.append(r)

    cont = work / "continuous"
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(cont), "joints": J2,
                                      "auto_split_gap_s": 0.5})
    r = Result("rec-continuous-clock-restart", "messages",
               "recorder in continuous mode: the stamps jump 100 s back mid-stream (a "
               "restarted simulation), then the node is shut down")
    try:
        rec = rig.node.recorder
        with rig_case(r, rig):
            for k in range(10):
                rig.publish(JointState, "/joint_states", state(rig, k))
            wait_for(lambda: rec.accepted >= 10, 10.0)
            for k in range(10):
                rig.publish(JointState, "/joint_states", state(rig, k, offset_s=-100.0))
            wait_for(lambda: rec.accepted >= 20, 10.0)
    finally:
        rig.close()  # shutdown() writes the last segment of a continuous recording
    bags = find_bags(cont) if cont.is_dir() else []
    written = messages_in(cont)
    r.behaviour = (f"split into {len(bags)} demonstrations ({written} of 20 messages "
                   "written; the last at shutdown)")
    r.expect(len(bags) == 2, f"{len(bags)} bags, expected 2")
    r.lost = 0 if written == 20 else 1
    out.append(r)
    return out


def _duration(seconds: float):
    from rclpy.duration import Duration

    return Duration(nanoseconds=int(seconds * 1e9))


# --- sim_robot ----------------------------------------------------------------------------
def cases_sim_robot(lab: Lab) -> list[Result]:
    """sim_robot: commands it cannot apply, bad parameters, an unknown robot."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from policy_align_ros.nodes.sim_robot import SimRobot

    out: list[Result] = []
    joints = [f"arm_left_{i}_joint" for i in range(1, 8)]
    rig = NodeRig(lab, SimRobot, {"joints": joints, "command_timeout_s": 5.0})
    states: list[JointState] = []
    rig.probe.create_subscription(JointState, "/joint_states", states.append, 100)
    try:
        sim = rig.node

        def command_case(case, tried, data):
            r = Result(case, "messages", tried)
            wait_for(lambda: len(states) > 0, 10.0)
            with rig_case(r, rig):
                start = np.array(sim.sim.q)
                bad = sim._bad_commands
                rig.publish(Float64MultiArray, "/velocity_controller/commands",
                            Float64MultiArray(data=[float(v) for v in data]))
                wait_for(lambda: sim._bad_commands > bad, 10.0)
                n = len(states)
                wait_for(lambda: len(states) >= n + 5, 10.0)  # a few integration steps
                moved = float(np.abs(np.array(sim.sim.q) - start).max())
            r.data.update(bad=sim._bad_commands - bad, moved=moved)
            r.behaviour = (f"ignored and counted ({sim._bad_commands} so far, warned at most "
                           f"every 2 s); the joints moved {moved:.3g} rad")
            r.expect(sim._bad_commands == bad + 1, "the command was not counted as ignored")
            r.expect(moved == 0.0, "the robot moved on a command it should ignore")
            out.append(r)

        command_case("sim-cmd-wrong-length", "Float64MultiArray of 3 values to a 7-joint "
                     "sim_robot", [0.1, 0.1, 0.1])
        command_case("sim-cmd-nan", "Float64MultiArray with a NaN velocity",
                     [float("nan")] + [0.0] * 6)
        command_case("sim-cmd-inf", "Float64MultiArray with an inf velocity",
                     [float("inf")] + [0.0] * 6)
        command_case("sim-cmd-empty", "an empty Float64MultiArray", [])
        p = _param_case
        out.append(p(rig, "sim-initial-positions-length",
                     "sim_robot `initial_positions` with 3 values for 7 joints",
                     "initial_positions", [0.0, 0.0, 0.0], "initial_positions"))
        out.append(p(rig, "sim-initial-positions-nan", "sim_robot `initial_positions` with NaN",
                     "initial_positions", [float("nan")] + [0.0] * 6, "initial_positions"))
        out.append(p(rig, "sim-command-timeout-nan", "sim_robot `command_timeout_s: nan`",
                     "command_timeout_s", float("nan")))
        out.append(p(rig, "sim-command-timeout-zero", "sim_robot `command_timeout_s: 0.0`",
                     "command_timeout_s", 0.0))
        out.append(p(rig, "sim-rate-read-only", "sim_robot `rate_hz: 10.0` at run time",
                     "rate_hz", 10.0, "read-only"))
    finally:
        rig.close()
    if not lab.start_ups:
        return out
    r = Result("sim-start-unknown-robot", "parameters",
               "`sim_robot --ros-args -p robot:=no_such_robot` (start-up)")
    _start_refused(r, node_start(lab, "sim_robot", "-p", "robot:=no_such_robot"),
                   "no_such_robot")
    out.append(r)
    r = Result("sim-start-unknown-joint", "parameters",
               "`sim_robot --ros-args -p 'joints:=[arm_left_1_joint, no_such_joint]'`")
    _start_refused(r, node_start(lab, "sim_robot", "-p",
                                 "joints:=[arm_left_1_joint, no_such_joint]"),
                   "no_such_joint")
    out.append(r)
    r = Result("sim-start-joints-empty", "parameters", "`sim_robot --ros-args -p 'joints:=[]'`")
    _start_refused(r, node_start(lab, "sim_robot", "-p", "joints:=[]"), "at least one joint")
    out.append(r)
    return out


# --- learner ------------------------------------------------------------------------------
def cases_learner(lab: Lab) -> list[Result]:
    """learner: bad parameters, learning without data, learning while learning."""
    from std_srvs.srv import Trigger

    from policy_align_ros.nodes.learner import Learner

    out: list[Result] = []
    work = lab.path("learner")
    big = work / "big"
    write_good_dataset(big, 60, seed=3)  # a fit that takes long enough to overlap
    (work / "empty").mkdir()
    rig = NodeRig(lab, Learner, {"dataset_dir": str(big), "model_path": str(work / "m.npz")})
    try:
        p = _param_case
        out.append(p(rig, "learner-sigma-word", "learner `sigma: huge`", "sigma", "huge",
                     "sigma"))
        out.append(p(rig, "learner-sigma-negative", "learner `sigma: '-1'`", "sigma", "-1",
                     "sigma"))
        out.append(p(rig, "learner-sigma-nan", "learner `sigma: nan`", "sigma", "nan",
                     "sigma"))
        out.append(p(rig, "learner-holdout-out-of-range", "learner `holdout_fraction: 1.5`",
                     "holdout_fraction", 1.5))
        out.append(p(rig, "learner-dataset-dir-empty", "learner `dataset_dir: ''`",
                     "dataset_dir", "", "dataset_dir"))
        out.append(p(rig, "learner-joints-repeated", "learner `joints: [j1, j1]`",
                     "joints", ["j1", "j1"], "joints"))
        out.append(p(rig, "learner-gap-negative", "learner `gap_s: -1.0`", "gap_s", -1.0))
        out.append(p(rig, "learner-seed-wrong-type", "learner `seed: 'abc'` (string)",
                     "seed", "abc"))

        r = Result("learner-learn-while-learning", "services",
                   "learner `~/learn` twice at once (60 demonstrations)")
        with rig_case(r, rig):
            client = rig.client(Trigger, "/learner/learn")
            client.wait_for_service(timeout_sec=10.0)
            first = client.call_async(Trigger.Request())
            second = client.call_async(Trigger.Request())
            wait_for(lambda: first.done() and second.done(), 300.0)
        answers = [f.result() for f in (first, second) if f.done()]
        refused = [a for a in answers if not a.success]
        r.data["answers"] = [(a.success, a.message) for a in answers]
        r.behaviour = "; ".join(
            f"success={str(a.success).lower()}: {_short(a.message, 90)}" for a in answers)
        r.expect(len(answers) == 2, "a call was not answered")
        r.expect(len(refused) == 1 and "already" in refused[0].message,
                 "not exactly one call refused as already running")
        out.append(r)

        s = _service_case
        learn = lambda: _trigger(rig, "/learner/learn")  # noqa: E731
        rig.set_param("dataset_dir", str(work / "empty"))
        out.append(s(rig, "learner-learn-empty-dataset",
                     "learner `~/learn` with an empty `dataset_dir`", learn, False, "empty"))
        rig.set_param("dataset_dir", str(work / "missing"))
        out.append(s(rig, "learner-learn-missing-dataset",
                     "learner `~/learn` with a `dataset_dir` that does not exist", learn,
                     False, "missing"))
        one = lab.dataset_with("learner_one", n_good=1)
        rig.set_param("dataset_dir", str(one))
        out.append(s(rig, "learner-learn-one-demo",
                     "learner `~/learn` with a single demonstration", learn, False, "2"))
        (work / "a_file").write_text("x")
        rig.set_param("dataset_dir", str(lab.good_dataset()))
        rig.set_param("model_path", str(work / "a_file" / "m.npz"))
        out.append(s(rig, "learner-learn-model-under-file",
                     "learner `~/learn` with `model_path` under a file", learn, False,
                     "a_file"))
    finally:
        rig.close()
    r = Result("learner-start-bad-sigma", "parameters",
               "`learner --ros-args -p sigma:=huge` (start-up)")
    _start_refused(r, node_start(lab, "learner", "-p", "sigma:=huge"), "sigma")
    out.append(r)
    return out


# --- demonstrator ---------------------------------------------------------------------------
def cases_demonstrator(lab: Lab) -> list[Result]:
    """demonstrator: parameters at run time and at start-up, no recorder to bracket demos."""
    from policy_align_ros.nodes.demonstrator import Demonstrator

    out = []
    rig = NodeRig(lab, Demonstrator, {"joints": ARM, "constraint_frames": ["arm_left_7_link"],
                                      "service_timeout_s": 600.0})
    try:
        out.append(_param_case(rig, "demo-gain-read-only", "demonstrator `gain: 5.0` at run "
                               "time (read-only)", "gain", 5.0, "read-only"))
        out.append(_param_case(rig, "demo-num-demos-wrong-type",
                               "demonstrator `num_demos: 'many'` (string)", "num_demos",
                               "many"))
    finally:
        rig.close()
    if not lab.start_ups:
        return out
    for case, tried, args, needle in (
            ("demo-start-attractor-length", "`demonstrator -p 'attractor:=[0.0, 0.0]'` "
             "(18 joints)", ["-p", "attractor:=[0.0, 0.0]"], "attractor"),
            ("demo-start-unknown-frame", "`demonstrator -p 'constraint_frames:=[no_frame]'`",
             ["-p", "constraint_frames:=[no_frame]"], "no_frame"),
            ("demo-start-no-recorder", "`demonstrator` with no recorder running "
             "(`service_timeout_s:=1.0`)", ["-p", "service_timeout_s:=1.0"], "recorder")):
        r = Result(case, "parameters" if "recorder" not in case else "services", tried)
        _start_refused(r, node_start(lab, "demonstrator", *args), needle)
        out.append(r)
    return out


# --- executor -------------------------------------------------------------------------------
ARM = [f"arm_left_{i}_joint" for i in range(1, 8)]


def _fit_model(path: Path, joints: Sequence[str], center: np.ndarray) -> Path:
    """A PolicyAlign model on ``joints`` of 8 demonstrations converging to ``center``."""
    from policy_align_ros.learning import PolicyAlign, Trajectory

    rng = np.random.default_rng(0)
    t = np.arange(40) * 0.05
    trajs = []
    for _ in range(8):
        q0 = center + rng.normal(scale=0.3, size=len(joints))
        trajs.append(Trajectory(center + (q0 - center) * np.exp(-t)[:, None], t))
    PolicyAlign(sigma="medium").fit(trajs, joint_names=list(joints)).save(path)
    return path


STATE_TIMEOUT_S = 2.0


class _Feeder:
    """Publishes valid joint states (node-clock stamps) every 20 ms while on."""

    def __init__(self, rig: NodeRig, joints: Sequence[str], q: np.ndarray) -> None:
        from sensor_msgs.msg import JointState

        self.rig, self.joints, self.q = rig, list(joints), q
        self._type = JointState
        self.last_stamp = None  # of the last message published by the thread
        # Stamping and publishing happen under one lock, for the thread's messages and for
        # inject()'s: otherwise a message stamped just before an injected valid one could
        # be published after it and read, rightly, as a stamp going backwards.
        self._lock = threading.Lock()
        self._on = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def message(self, names=None, positions=None, stamp=None):
        msg = self._type(name=list(self.joints if names is None else names),
                         position=[float(v) for v in (self.q if positions is None
                                                      else positions)])
        msg.header.stamp = (self.rig.node.get_clock().now().to_msg() if stamp is None
                            else stamp)
        return msg

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            if self._on.is_set() and self.rig.context.ok():
                with self._lock:
                    msg = self.message()
                    self.rig.publish(self._type, "/joint_states", msg)
                    self.last_stamp = msg.header.stamp

    def inject(self, make_msg) -> None:
        """Publish ``make_msg()`` on the feeder's topic, ordered with the feeder's own."""
        with self._lock:
            self.rig.publish(self._type, "/joint_states", make_msg())

    def on(self) -> None:
        self._on.set()

    def off(self) -> None:
        self._on.clear()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


def cases_executor(lab: Lab) -> list[Result]:
    """executor: enable without a model, bad constraints and models, broken joint states."""
    from std_msgs.msg import Float64MultiArray, String
    from std_srvs.srv import SetBool

    from policy_align_ros.kinematics import Robot
    from policy_align_ros.nodes.executor import Executor

    out: list[Result] = []
    work = lab.path("executor")
    center = Robot.load("talos", ARM).neutral()
    model = _fit_model(work / "model.npz", ARM, center)
    other = _fit_model(work / "other.npz", ["a", "b"], np.zeros(2))
    (work / "notes.txt").write_text("not a model\n")
    # 2 s, not the default 0.5 s: on a loaded 2-core machine the feeder thread can stall
    # for most of a second, which would disarm for staleness in the middle of a case
    # about something else.
    base = {"robot": "talos", "joints": ARM, "rate_hz": 50.0,
            "state_timeout_s": STATE_TIMEOUT_S, "max_acceleration": 5.0, "controller": ""}

    def enable(rig, on=True):
        return rig.call(SetBool, "/executor/enable", SetBool.Request(data=on))

    s = _service_case
    p = _param_case
    rig = NodeRig(lab, Executor, dict(base))
    try:
        out.append(s(rig, "exe-enable-without-model", "executor `~/enable true` with no model",
                     lambda: enable(rig), False, "no model"))
        out.append(p(rig, "exe-constraints-bad-yaml",
                     "executor `constraints: '[{type: plane, frame: arm_left_7_link'`",
                     "constraints", "[{type: plane, frame: arm_left_7_link", "constraints"))
        out.append(p(rig, "exe-constraints-unknown-frame",
                     "executor `constraints` on frame `no_such_link`", "constraints",
                     "[{type: plane, frame: no_such_link, normal: [0, 0, 1]}]",
                     "no_such_link"))
        out.append(p(rig, "exe-constraints-normal-length",
                     "executor plane constraint with `normal: [0, 1]` (2 values)",
                     "constraints", "[{type: plane, frame: arm_left_7_link, normal: [0, 1]}]",
                     "normal"))
        out.append(p(rig, "exe-constraints-zero-normal",
                     "executor plane constraint with `normal: [0, 0, 0]`", "constraints",
                     "[{type: plane, frame: arm_left_7_link, normal: [0, 0, 0]}]", "normal"))
        out.append(p(rig, "exe-constraints-unknown-type", "executor `constraints: "
                     "[{type: cylinder}]`", "constraints", "[{type: cylinder}]", "cylinder"))
        out.append(p(rig, "exe-constraints-not-a-list", "executor `constraints: '42'`",
                     "constraints", "42", "constraints"))
        out.append(p(rig, "exe-constraints-wrong-type", "executor `constraints: "
                     "[{type: joints, joints: 3}]` (a number for the joint list)",
                     "constraints", "[{type: joints, joints: 3}]", "non-empty list"))
        out.append(p(rig, "exe-max-velocity-nan", "executor `max_velocity: nan`",
                     "max_velocity", float("nan")))
        out.append(p(rig, "exe-max-velocity-negative", "executor `max_velocity: -1.0`",
                     "max_velocity", -1.0))
        out.append(p(rig, "exe-max-acceleration-inf", "executor `max_acceleration: inf`",
                     "max_acceleration", float("inf")))
        out.append(p(rig, "exe-model-path-missing", "executor `model_path` to a missing file",
                     "model_path", str(work / "missing.npz"), "missing.npz"))
        out.append(p(rig, "exe-model-path-not-a-model", "executor `model_path` to a text file",
                     "model_path", str(work / "notes.txt"), "notes.txt"))
        out.append(p(rig, "exe-model-path-other-joints",
                     "executor `model_path` to a model of joints a, b", "model_path",
                     str(other), "model"))
        out.append(p(rig, "exe-robot-read-only", "executor `robot: panda` at run time",
                     "robot", "panda", "read-only"))
        out.append(p(rig, "exe-joints-read-only", "executor `joints` changed at run time",
                     "joints", ARM[::-1], "read-only"))
        out.append(p(rig, "exe-controller-bad-name", "executor `controller: 'no such//node'`",
                     "controller", "no such//node", "controller"))
    finally:
        rig.close()

    rig = NodeRig(lab, Executor, dict(base, model_path=str(model)))
    commands: list[np.ndarray] = []
    rig.probe.create_subscription(Float64MultiArray, "/velocity_controller/commands",
                                  lambda m: commands.append(np.array(m.data)), 1000)
    feeder = _Feeder(rig, ARM, center + 0.2)
    try:
        exe = rig.node
        out.append(s(rig, "exe-enable-no-joint-states",
                     "executor `~/enable true` with a model but no joint state yet",
                     lambda: enable(rig), False, "refused"))
        feeder.on()

        def state_case(case, tried, make_msg, disarms, reason=None):
            # A message that must be ignored may still meet a disarm it did not cause: on
            # an overloaded machine the feeder thread can stall past state_timeout_s. That
            # says nothing about the message, so the case is tried again (at most twice).
            for _ in range(3):
                r = attempt_state_case(case, tried, make_msg, disarms, reason)
                if disarms or exe.controller.armed or "stale" not in exe.controller.zero_reason:
                    break
            out.append(r)
            return r

        def attempt_state_case(case, tried, make_msg, disarms, reason):
            r = Result(case, "messages", tried)
            armed = wait_for(lambda: enable(rig).success and exe.controller.armed, 10.0)
            wait_for(lambda: len(commands) > 0 and np.abs(commands[-1]).max() > 0, 10.0)
            if not r.expect(armed, "could not arm before the case"):
                return r
            with rig_case(r, rig):
                rejected = sum(exe.rejected_states.values())
                before = dict(exe.rejected_states)
                n = len(commands)
                feeder.inject(make_msg)
                if disarms:
                    wait_for(lambda: not exe.controller.armed and any(
                        not c.any() for c in commands[n:]), 5.0)
                elif reason is not None:
                    wait_for(lambda: sum(exe.rejected_states.values()) > rejected, 5.0)
                    time.sleep(0.2)
                else:
                    time.sleep(0.3)  # accepted: nothing to wait for but a few ticks
            zero = any(not c.any() for c in commands[n:])
            counted = sum(exe.rejected_states.values()) - rejected
            r.data.update(armed=exe.controller.armed, zero=zero, counted=counted,
                          rejected=dict(exe.rejected_states))
            reasons = ", ".join(f"`{k}`" for k, v in exe.rejected_states.items()
                                if v > before.get(k, 0)) or "nothing"
            if disarms:
                r.behaviour = ("rejected, zero command at once, disarmed until `~/enable`"
                               if zero and not exe.controller.armed else
                               f"armed={exe.controller.armed}, zero command={zero}")
                r.expect(not exe.controller.armed, "still armed after the message")
                r.expect(zero, "no zero command after the message")
            elif reason is None:
                r.behaviour = f"accepted (matched by name), still armed={exe.controller.armed}"
                r.expect(exe.controller.armed, "disarmed by a valid message")
                r.expect(counted == 0, "a valid message was rejected")
            else:
                r.behaviour = (f"ignored and counted, still armed={exe.controller.armed}")
                r.expect(exe.controller.armed, "disarmed by a message meant for someone else")
            if reasons != "nothing" or reason is not None:
                r.behaviour += f"; counted as {reasons}"
            if reason is not None:
                r.expect(exe.rejected_states.get(reason, 0) > 0, f"not counted as {reason}")
            return r

        from builtin_interfaces.msg import Time
        from rclpy.time import Time as RclpyTime

        q = center + 0.2
        now = exe.get_clock().now
        state_case("exe-msg-joint-twice", "JointState naming arm_left_1_joint twice (the "
                   "second with another value), executor armed",
                   lambda: feeder.message(ARM + [ARM[0]], list(q) + [q[0] + 0.5]), True,
                   "duplicate_joints")
        state_case("exe-msg-nan", "JointState with a NaN position, executor armed",
                   lambda: feeder.message(positions=[np.nan] + list(q[1:])), True,
                   "non_finite")
        state_case("exe-msg-lengths", "JointState with 7 names and 6 positions, armed",
                   lambda: feeder.message(positions=list(q[:6])), True, "length_mismatch")
        state_case("exe-msg-stamp-old", "JointState stamped 10 s ago, armed",
                   lambda: feeder.message(stamp=(now() - _duration(10.0)).to_msg()), True)
        state_case("exe-msg-stamp-zero", "JointState with a zero stamp, armed",
                   lambda: feeder.message(stamp=Time()), True)
        state_case("exe-msg-stamp-future", "JointState stamped 10 s in the future, armed",
                   lambda: feeder.message(stamp=(now() + _duration(10.0)).to_msg()), True)
        # Before the feeder's last stamp, not the clock's: on a loaded machine the feeder
        # thread can fall more than 0.3 s behind, and "now - 0.3 s" is then in order.
        state_case("exe-msg-stamp-backwards", "JointState stamped 0.3 s before the last one",
                   lambda: feeder.message(stamp=(RclpyTime.from_msg(feeder.last_stamp)
                                                 - _duration(0.3)).to_msg()), True)
        state_case("exe-msg-other-joints", "JointState of other joints only (another "
                   "publisher), armed", lambda: feeder.message(["x1", "x2"], [0.0, 0.0]),
                   False, "unknown_joints")
        state_case("exe-msg-extra-joint", "JointState with the 7 joints and 2 more (another "
                   "order), armed", lambda: feeder.message(
                       ["x1"] + ARM[::-1] + ["x2"], [0.0] + list(q[::-1]) + [0.0]), False)
        state_case("exe-msg-missing-joint", "JointState with 6 of the 7 joints, armed",
                   lambda: feeder.message(ARM[:6], list(q[:6])), False, "missing_joints")

        def announce(case, tried, path):
            r = Result(case, "messages", tried)
            with rig_case(r, rig):
                before = exe.model_path
                rig.publish(String, "/learner/model", String(data=str(path)))
                time.sleep(1.0)  # a refusal changes nothing, so there is nothing to wait for
            r.behaviour = ("refused (logged); the loaded model stays" if
                           exe.model_path == before else f"loaded {exe.model_path}")
            r.expect(exe.model_path == before, "the model changed")
            out.append(r)

        feeder.off()
        wait_for(lambda: not exe.controller.armed, 3.0 * STATE_TIMEOUT_S)  # states went stale
        time.sleep(STATE_TIMEOUT_S + 0.1)  # longer than state_timeout_s without a state
        out.append(s(rig, "exe-enable-stale-states",
                     f"executor `~/enable true` {STATE_TIMEOUT_S + 0.1:.1f} s after the last "
                     f"joint state (`state_timeout_s` {STATE_TIMEOUT_S})", lambda: enable(rig),
                     False, "refused"))
        feeder.on()
        announce("exe-announce-missing-model", "`/learner/model` announcing a missing file",
                 work / "missing.npz")
        announce("exe-announce-not-a-model", "`/learner/model` announcing a text file",
                 work / "notes.txt")
        announce("exe-announce-other-joints", "`/learner/model` announcing a model of "
                 "joints a, b", other)
    finally:
        feeder.close()
        rig.close()
    out.append(_executor_clock_jump(lab, base, model, center))
    if not lab.start_ups:
        return out
    for case, tried, args, needle in (
            ("exe-start-unknown-robot", "`executor -p robot:=no_such_robot`",
             ["-p", "robot:=no_such_robot"], "no_such_robot"),
            ("exe-start-unknown-joint", "`executor -p 'joints:=[arm_left_1_joint, nope]'`",
             ["-p", "joints:=[arm_left_1_joint, nope]"], "nope"),
            ("exe-start-joints-repeated",
             "`executor -p 'joints:=[arm_left_1_joint, arm_left_1_joint]'`",
             ["-p", "joints:=[arm_left_1_joint, arm_left_1_joint]"], "joints"),
            ("exe-start-bad-constraints", "`executor -p 'constraints:=[{type: plane'`",
             ["-p", "constraints:=[{type: plane"], "constraints"),
            ("exe-start-joints-empty", "`executor -p 'joints:=[]'`",
             ["-p", "joints:=[]"], "non-empty list"),
            ("exe-start-model-missing", "`executor -p model_path:=/nonexistent/model.npz`",
             ["-p", "model_path:=/nonexistent/model.npz"], "nonexistent")):
        r = Result(case, "parameters", tried)
        _start_refused(r, node_start(lab, "executor", *args), needle)
        out.append(r)
    return out


def _executor_clock_jump(lab: Lab, base: dict, model: Path, center: np.ndarray) -> Result:
    """An armed executor on sim time whose ``/clock`` jumps 10 s back (a restarted sim)."""
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import SetBool

    from policy_align_ros.nodes.executor import Executor

    r = Result("exe-clock-jumps-back", "messages",
               "`/clock` jumps 10 s back while the executor (use_sim_time) is armed")
    rig = NodeRig(lab, Executor, dict(base, model_path=str(model), use_sim_time=True))
    commands: list[np.ndarray] = []
    rig.probe.create_subscription(Float64MultiArray, "/velocity_controller/commands",
                                  lambda m: commands.append(np.array(m.data)), 1000)
    sim_ns = [1_000 * 10**9]
    stop = threading.Event()

    def tick():  # the simulated clock: 20 ms of sim time every 20 ms
        from rclpy.time import Time

        while not stop.wait(0.02):
            sim_ns[0] += 20 * MS
            if rig.context.ok():
                rig.publish(Clock, "/clock", Clock(clock=Time(nanoseconds=sim_ns[0]).to_msg()))

    clock = threading.Thread(target=tick, daemon=True)
    clock.start()
    feeder = _Feeder(rig, ARM, center + 0.2)
    try:
        exe = rig.node
        wait_for(lambda: exe.get_clock().now().nanoseconds > 1_000 * 10**9, 10.0)
        feeder.on()
        armed = wait_for(lambda: rig.call(SetBool, "/executor/enable",
                                          SetBool.Request(data=True)).success, 10.0)
        wait_for(lambda: len(commands) > 0 and np.abs(commands[-1]).max() > 0, 10.0)
        if r.expect(armed and exe.controller.armed, "could not arm before the case"):
            with rig_case(r, rig):
                n = len(commands)
                sim_ns[0] -= 10 * 10**9
                wait_for(lambda: not exe.controller.armed and any(
                    not c.any() for c in commands[n:]), 5.0)
            zero = any(not c.any() for c in commands[n:])
            r.behaviour = ("zero command at once, disarmed until `~/enable`"
                           if zero and not exe.controller.armed else
                           f"armed={exe.controller.armed}, zero command={zero}")
            r.expect(not exe.controller.armed, "still armed after the clock jumped back")
            r.expect(zero, "no zero command after the jump")
    finally:
        stop.set()
        clock.join(timeout=2.0)
        feeder.close()
        rig.close()
    return r


# --- the table ------------------------------------------------------------------------------
#: Case groups in table order: (name, function).
GROUPS: list[tuple[str, Callable[[Lab], list[Result]]]] = [
    ("cli-learn", cases_cli_learn),
    ("cli-misc", cases_cli_misc),
    ("cli-ros", cases_cli_ros),
    ("cli-demo", cases_cli_demo),
    ("bags", cases_bags),
    ("recorder", cases_recorder),
    ("learner", cases_learner),
    ("executor", cases_executor),
    ("sim_robot", cases_sim_robot),
    ("demonstrator", cases_demonstrator),
]


def run_groups(lab: Lab, only: Sequence[str] = (), log: Callable[[str], None] | None = None
               ) -> list[Result]:
    """Run the groups named in ``only`` (``cli`` selects every ``cli-*``; all when empty)."""
    results = []
    for name, group in GROUPS:
        if only and not any(name == o or name.startswith(o + "-") for o in only):
            continue
        start = time.monotonic()
        try:
            rows = group(lab)
        except Exception:  # noqa: BLE001 - a harness failure is reported, not hidden
            rows = [Result(f"{name}-harness", "harness", f"group {name}",
                           behaviour="the harness failed: " + _short(traceback.format_exc(),
                                                                     300),
                           problems=["harness failure"])]
        results.extend(rows)
        if log is not None:
            bad = sum(not r.ok for r in rows)
            log(f"{name}: {len(rows)} case(s), {bad} with problems, "
                f"{time.monotonic() - start:.0f} s")
    return results


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def markdown(results: Sequence[Result], command: str) -> str:
    """The table and its totals as Markdown."""
    crashes = sum(r.crash for r in results)
    tracebacks = sum(r.traceback for r in results)
    lost = sum(r.lost or 0 for r in results)
    problems = [r for r in results if r.problems]
    by_area = {a: sum(r.area == a for r in results) for a in AREAS}
    lines = [
        f"{len(results)} bad inputs ("
        + ", ".join(f"{n} {a}" for a, n in by_area.items() if n)
        + f"): **{crashes} crashes, {tracebacks} tracebacks, {lost} finished demonstrations "
        f"lost**; {len(problems)} behaviour(s) differ from what a robot owner expects "
        "(column *verdict*).",
        "",
        f"Produced by `{command}`.",
        "",
        "| # case | area | bad input | what the package did | crash | traceback | demos lost "
        "| verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for k, r in enumerate(results, 1):
        verdict = "ok" if not r.problems else "**PROBLEM**: " + "; ".join(r.problems)
        lines.append(
            f"| {k} `{r.case}` | {r.area} | {_cell(r.tried)} | {_cell(r.behaviour)} | "
            f"{'**yes**' if r.crash else 'no'} | {'**yes**' if r.traceback else 'no'} | "
            f"{'-' if r.lost is None else r.lost} | {_cell(verdict)} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the cases and print (or write) the table; exit 1 if any row is not ok."""
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--only", default="", help="comma-separated groups or areas")
    parser.add_argument("--in-process", action="store_true",
                        help="run CLI cases through cli.main instead of subprocesses")
    parser.add_argument("--domain-base", type=int, default=60)
    parser.add_argument("--markdown", default=None,
                        help="write the table into this file between the markers")
    parser.add_argument("--keep", action="store_true", help="keep the scratch directory")
    args = parser.parse_args(argv)
    only = [o for o in args.only.split(",") if o]
    import tempfile

    workdir = Path(tempfile.mkdtemp(prefix="robustness_"))
    try:
        lab = Lab(workdir, args.domain_base, cli_subprocess=not args.in_process)
        results = run_groups(lab, only, log=lambda t: print(t, file=sys.stderr, flush=True))
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    command = "python tools/robustness.py" + (f" --only {args.only}" if only else "") + (
        " --in-process" if args.in_process else "") + (
        f" --markdown {args.markdown}" if args.markdown else "")
    table = markdown(results, command)
    if args.markdown:
        _write_between_markers(Path(args.markdown), table)
    print(table)
    return 0 if all(r.ok for r in results) else 1


BEGIN, END = "<!-- robustness table: begin -->", "<!-- robustness table: end -->"


def _write_between_markers(path: Path, table: str) -> None:
    """Replace the text between the markers of ``path`` (append both if missing)."""
    text = path.read_text() if path.exists() else ""
    block = f"{BEGIN}\n{table}{END}"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        text = head + block + rest.split(END, 1)[1]
    else:
        text = text + ("\n" if text and not text.endswith("\n") else "") + block + "\n"
    path.write_text(text)


if __name__ == "__main__":
    sys.exit(main())
