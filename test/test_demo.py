"""``policy-align demo``: a short end-to-end run (separate node processes, domain 220) and
the ROS-free parts of the report (new start states, targets, the printed report)."""

import argparse
import json
import os
from pathlib import Path

import numpy as np
import pytest

from policy_align_ros.client.demo import (
    MIN_START_SEPARATION,
    DemoSettings,
    StageError,
    Task,
    _settings,
    _streams,
    _targets,
    new_starts,
    repeated_steps,
    report_text,
    run_demo,
    stale_ticks,
)
from policy_align_ros.data import load_dataset
from policy_align_ros.kinematics import Robot
from policy_align_ros.learning import Trajectory
from policy_align_ros.nodes._common import DEFAULT_JOINTS

ARM = [f"arm_left_{i}_joint" for i in range(1, 8)]
HAND = "arm_left_7_link"
RUN_KEYS = {"name", "start", "start_distance", "final_distance", "expert_final_distance",
            "constraint", "held_frame_drift_mm"}


def _processes_mentioning(text: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if text in cmdline:
                pids.append(int(entry.name))
    return pids


def test_short_demo_writes_the_report_contract_and_cleans_up(tmp_path, capsys):
    out = tmp_path / "demo"
    # The left arm only: a quadratic potential in 7 joints is learnt from 6 short
    # demonstrations (in 18 joints that takes about 24, see DEFAULT_DEMOS). With 4, a
    # loaded machine's missed control periods in one recording could cost the fresh
    # demonstrations' nCPE its bound (0.26 once in about ten runs; 0.002 with 6).
    args = argparse.Namespace(robot="talos", out=str(out), demos=8, demo_duration_s=2.0,
                              run_duration_s=2.0, free_runs=1, held_runs=1, fresh_demos=2,
                              domain_id=220, seed=5, joints=ARM, frames=[HAND])
    code = run_demo(args)
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "demonstrator finished: 8 demonstrations recorded" in printed.out

    report = json.loads((out / "report.json").read_text())
    # DESIGN section 7: the contract's keys and their meaning.
    assert report["robot"] == "talos" and report["state"] == "joints"
    demos = report["demonstrations"]
    assert demos["recorded"] == 8
    assert demos["training"] + demos["held_out"] == 8 and demos["discarded"] >= 0
    assert demos["held_out"] == 2  # the learner's holdout_fraction 0.2 of 8
    assert report["sigma2"] > 0 and report["fit_time_s"] > 0
    assert 0 <= report["heldout_ncpe_fresh"] < 0.2
    assert report["total_time_s"] > 0
    names = [run["name"] for run in report["runs"]]
    assert names == ["unconstrained", "unseen_constraint"]
    for run in report["runs"]:
        assert RUN_KEYS <= set(run)
        assert run["start"] == "new" and run["start_separation_rad"] >= MIN_START_SEPARATION
    free, held = report["runs"]
    assert free["constraint"] is None and free["held_frame_drift_mm"] is None
    assert held["constraint"] == [{"type": "position", "frame": "arm_left_7_link"}]
    assert held["held_frame_drift_mm"] >= 0
    # Real progress: the learnt policy brings the robot towards the expert's goal.
    assert free["final_distance"] < 0.5 * free["start_distance"]
    assert held["final_distance"] < held["start_distance"]
    assert report["sim"]["executor_periods"] > 0
    assert report["sim"]["real_time_factor"] > 1  # the graph ran on simulated time

    # The printed report and the plots come from report.json and the saved traces.
    text = (out / "report.txt").read_text()
    assert text.strip() == report_text(report).strip()
    assert text.strip() in printed.out
    traces = np.load(out / "traces.npz")
    assert traces["run0_q"].shape[1] == len(ARM)
    assert (out / "demo_distance.png").stat().st_size > 0
    assert (out / "demo_hands.png").stat().st_size > 0

    trajs, joints, _ = load_dataset([out / "demos"])
    assert len(trajs) == 8 and joints == ARM
    assert (out / "model.npz").is_file()
    assert _processes_mentioning(str(out / "params.yaml")) == []


def test_new_starts_come_from_the_start_distribution_and_avoid_recorded_ones():
    robot = Robot.load("talos", DEFAULT_JOINTS)
    task = Task(robot, _settings(argparse.Namespace(seed=0)))
    streams = _streams(0)
    recorded = new_starts(task, np.random.default_rng(1), 20, np.empty((0, robot.nq)))
    starts = new_starts(task, streams["starts"], 50, recorded)
    gaps = np.linalg.norm(starts[:, None, :] - recorded[None], axis=2)
    assert gaps.min() >= MIN_START_SEPARATION
    # Spread like the demonstrators' N(q_c, 0.1 I), clipped to the limits.
    assert np.all((starts >= robot.lower) & (starts <= robot.upper))
    assert 0.05 < np.var(starts - task.attractor) < 0.15
    # A recorded start that every draw would hit is refused, not silently reused.
    with pytest.raises(StageError, match="new start states"):
        new_starts(Task(robot, DemoSettings(start_variance=0.0)), streams["starts"], 1,
                   task.attractor[None])


def test_seed_sets_every_stream_and_settings_are_checked():
    a, b = _streams(3), _streams(3)
    assert a["demonstrator"] == b["demonstrator"]
    assert np.array_equal(a["starts"].random(3), b["starts"].random(3))
    assert _streams(4)["demonstrator"] != a["demonstrator"]
    with pytest.raises(ValueError, match="state"):
        _settings(argparse.Namespace(state="elbows"))
    with pytest.raises(ValueError, match="demos"):
        _settings(argparse.Namespace(demos=2))
    assert run_demo(argparse.Namespace(state="elbows")) == 2


def test_targets_and_report_text_follow_the_numbers():
    run = {"name": "unconstrained", "id": "unconstrained_1", "start": "new",
           "start_distance": 1.0, "final_distance": 0.04, "expert_final_distance": 0.001,
           "constraint": None, "held_frame_drift_mm": None}
    held = {**run, "name": "unseen_constraint", "id": "unseen_constraint_1",
            "final_distance": 0.06, "constraint": [{"type": "position", "frame": "f"}],
            "held_frame": "f", "held_frame_drift_mm": 1.5}
    report = {"robot": "talos", "state": "joints",
              "demonstrations": {"recorded": 5, "training": 4, "held_out": 1, "discarded": 0},
              "sigma2": 0.05, "fit_time_s": 1.0, "heldout_ncpe_fresh": 0.3,
              "runs": [run, held], "total_time_s": 10.0}
    targets = _targets(report)
    assert targets == {"heldout_ncpe_fresh <= 0.2": False,
                       "unconstrained_1: final <= 10% of start and <= 0.05 rad": True,
                       "unseen_constraint_1: final <= expert + 0.05 rad": False,
                       "unseen_constraint_1: held frame drift <= 1 mm": False}
    text = report_text({**report, "targets": targets})
    assert ("5 recorded, 4 for training (0 of them discarded, 0 too weakly connected to "
            "align and levelled by the global model), 1 held out") in text
    assert "1.0000 -> 0.0400; expert 0.0010" in text
    assert "f held, drift 1.50 mm" in text
    assert "heldout_ncpe_fresh <= 0.2: MISSED" in text


def test_unusable_out_directory_exits_2_with_the_reason(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert run_demo(argparse.Namespace(out=str(blocker / "demo"))) == 2
    assert "cannot be used as the output directory" in capsys.readouterr().err


def test_repeated_steps_find_a_command_integrated_twice():
    dt, v = 0.04, np.array([0.3, -0.2])
    q = [np.array([0.1, 0.7])]
    for command in (v, v * 0.9, v * 0.9, v * 0.8, np.zeros(2), np.zeros(2)):
        q.append(q[-1] + dt * command)  # the simulator's Euler step
    # Steps 2 and 3 use the same command (a missed period); standing still is no miss.
    np.testing.assert_array_equal(repeated_steps(np.array(q)),
                                  [False, True, False, False, False])
    assert stale_ticks([Trajectory(np.array(q), dt * np.arange(len(q)))]) == (5, 1)


# The demo with stand-in nodes that ignore SIGINT (as a learner busy in a fit does for a
# while), stopped by signals while its stages run.
_STUBBORN_GRAPH = """
import argparse, subprocess, sys, time
from policy_align_ros.client import demo

def start(self, name):
    code = "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); time.sleep(300)"
    self.procs[name] = subprocess.Popen([sys.executable, "-c", code, str(self.params)],
                                        start_new_session=True)

def stages(*args):
    print("running", flush=True)
    time.sleep(300)

demo.Graph.start, demo._stages = start, stages
try:
    sys.exit(demo.run_demo(argparse.Namespace(out=sys.argv[1], domain_id=221, plots=False)))
except KeyboardInterrupt:
    sys.exit(130)
"""


@pytest.mark.parametrize("signals", [("SIGHUP",), ("SIGINT", "SIGTERM")])
def test_signals_to_the_demo_leave_no_node_processes(tmp_path, signals):
    # The nodes run in their own sessions: a closed terminal (SIGHUP) reaches the demo
    # only, and a second signal during the clean-up must not cut it short.
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "demo"
    demo = subprocess.Popen([sys.executable, "-c", _STUBBORN_GRAPH, str(out)],
                            stdout=subprocess.PIPE, text=True)
    try:
        while (line := demo.stdout.readline()) and line.strip() != "running":
            pass  # the demo's own progress lines
        assert len(_processes_mentioning(str(out / "params.yaml"))) == 5
        for name in signals:
            demo.send_signal(getattr(signal, name))
            time.sleep(1.0)
        assert demo.wait(timeout=30) == 130
        assert _processes_mentioning(str(out / "params.yaml")) == []
    finally:
        demo.kill()
        demo.wait()
        for pid in _processes_mentioning(str(out / "params.yaml")):
            os.kill(pid, signal.SIGKILL)


def test_a_stalled_recording_names_its_wall_time_budget(monkeypatch):
    from policy_align_ros.client import demo

    class Clock:  # each reading 10 s after the one before, from a large monotonic origin
        now = 1e6

        @classmethod
        def monotonic(cls):
            cls.now += 10.0
            return cls.now

    class Proc:
        def poll(self):
            return None

    class Graph:
        procs = {"demonstrator": Proc()}

        def check(self, allow_exit=()):
            pass

        def tail(self, name):
            return ""

    class Conductor:
        progress = ""

        def now(self):
            return 0.0

        def spin(self, seconds):
            pass

    monkeypatch.setattr(demo, "time", Clock)
    s = DemoSettings(demos=3, demo_duration_s=2.0)  # 30 + 3 * (2 + 6) = 54 s
    with pytest.raises(StageError, match=r"not finished after 54 s"):
        demo._record(s, 0.0, Graph(), Conductor())
