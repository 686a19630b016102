"""``policy-align demo`` end to end: a short run of the whole graph (separate node
processes, domain 220), its exit statuses and its clean-up (domain 221)."""

import argparse
import json
import os
from pathlib import Path

import numpy as np
import pytest

from policy_align_ros.client.demo import report_text, run_demo
from policy_align_ros.client.demo.settings import MIN_START_SEPARATION
from policy_align_ros.data import load_dataset

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
    # training demonstrations (in 18 joints that takes about 24, see DEFAULT_DEMOS); fewer
    # can miss the fresh demonstrations' nCPE bound on a loaded machine.
    args = argparse.Namespace(robot="talos", out=str(out), demos=8, demo_duration_s=2.0,
                              run_duration_s=2.0, free_runs=1, held_runs=1, fresh_demos=2,
                              domain_id=220, seed=5, joints=ARM, frames=[HAND])
    code = run_demo(args)
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert len([bag for bag in (out / "demos").iterdir() if bag.is_dir()]) == 8

    report = json.loads((out / "report.json").read_text())
    # docs/design.md section 7: the contract's keys and their meaning.
    assert report["robot"] == "talos" and report["state"] == "joints"
    demos = report["demonstrations"]
    assert demos["recorded"] == 8
    assert demos["training"] + demos["held_out"] == 8
    assert demos["discarded"] <= demos["training"]  # discarded from the training split
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
    assert held["held_frame"] == HAND
    assert held["held_frame_final_drift_mm"] <= held["held_frame_drift_mm"]  # final <= max
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


def test_unusable_out_directory_exits_2_before_writing_anything(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert run_demo(argparse.Namespace(out=str(blocker / "demo"))) == 2
    # Refused before anything is written or started.
    assert list(tmp_path.iterdir()) == [blocker]
    assert blocker.read_text() == "not a directory"
    assert capsys.readouterr().err  # the reason is on stderr


# The demo with stand-in nodes that ignore SIGINT (as a learner busy in a fit does for a
# while), stopped by signals while its stages run.
_STUBBORN_GRAPH = """
import argparse, subprocess, sys, time
from policy_align_ros.client.demo import graph, main

def start(self, name):
    code = "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); time.sleep(300)"
    self.procs[name] = subprocess.Popen([sys.executable, "-c", code, str(self.params)],
                                        start_new_session=True)

def stages(*args):
    print("running", flush=True)
    time.sleep(300)

graph.Graph.start, main.run_stages = start, stages
try:
    sys.exit(main.run_demo(argparse.Namespace(out=sys.argv[1], domain_id=221, plots=False)))
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
