"""``policy-align demo``'s entry point: settings, the output directory, the graph's life.

Exit status: 0 when every stage succeeded, 1 when a stage failed (or an unconstrained run
did not end closer to its goal than it started), 2 on bad settings or an unusable output
directory. Every child process is stopped (SIGINT, then SIGKILL) whatever happens, also
on SIGTERM or SIGHUP.
"""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import sys
import time
from pathlib import Path

import numpy as np
import rclpy

from policy_align_ros.client.demo.conductor import Conductor
from policy_align_ros.client.demo.graph import Graph, write_params
from policy_align_ros.client.demo.plots import plot_report
from policy_align_ros.client.demo.report import report_text, save_traces
from policy_align_ros.client.demo.settings import (
    NODES,
    DemoSettings,
    StageError,
    pick_domain_id,
    random_streams,
    say,
    settings_from_args,
)
from policy_align_ros.client.demo.stages import run_stages
from policy_align_ros.client.demo.task import Task
from policy_align_ros.kinematics import Robot
from policy_align_ros.learning.model_io import atomic_write_text

__all__ = ["run_demo"]

#: Files and directories of an earlier run in ``--out``, removed before a run.
_RESULTS = ("demos", "report.json", "report.txt", "traces.npz", "model.npz")


def run_demo(args: argparse.Namespace) -> int:
    """Entry of ``policy-align demo``; returns 0 when every stage succeeded."""
    try:
        s = settings_from_args(args)
        domain = pick_domain_id(s.domain_id)
    except ValueError as err:
        print(f"[demo] {err}", file=sys.stderr, flush=True)
        return 2
    t0 = time.monotonic()
    s.out = s.out.resolve()
    try:
        _clear_results(s.out)
    except OSError as err:
        print(f"[demo] --out {s.out}: cannot be used as the output directory: {err}",
              file=sys.stderr, flush=True)
        return 2
    robot = Robot.load(s.robot, s.joints or None)
    s.joints = list(robot.joint_names)
    task = Task(robot, s)
    streams = random_streams(s.seed)
    params = s.out / "params.yaml"
    write_params(params, s, task, streams["demonstrator"])
    graph = Graph(s.out, params, domain)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    # The children run in their own sessions, so a closed terminal (SIGHUP) or a SIGTERM
    # reaches only this process: both must end in graph.stop(), like Ctrl-C.
    previous = {sig: signal.getsignal(sig)
                for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    _set_handlers({signal.SIGTERM: signal.default_int_handler,
                   signal.SIGHUP: signal.default_int_handler}, previous)
    conductor = None
    try:
        say(t0, f"robot {s.robot}: {len(s.joints)} joints, state {s.state}, seed {s.seed}, "
                f"ROS domain {domain}, sim time at {s.real_time_factor:g}x, output {s.out}")
        for name in NODES:
            graph.start(name)
        conductor = Conductor(context, s.joints, graph)
        report, traces = run_stages(s, t0, graph, conductor, task, streams)
        report["total_time_s"] = round(time.monotonic() - t0, 2)
        _publish(s, t0, report, traces)
        return 0
    except StageError as err:
        print(f"[demo] FAILED: {err}", file=sys.stderr, flush=True)
        return 1
    finally:
        # A second signal must not cut the clean-up short: nothing else stops the children.
        _set_handlers(dict.fromkeys(previous, signal.SIG_IGN), previous)
        try:
            graph.stop()
            if conductor is not None:
                conductor.close()
            rclpy.try_shutdown(context=context)
        finally:
            _set_handlers(previous, previous)


def _clear_results(out: Path) -> None:
    """Create ``out`` and remove an earlier run's results from it (OSError if unusable)."""
    out.mkdir(parents=True, exist_ok=True)
    for stale in _RESULTS:
        path = out / stale
        if path.is_dir():
            shutil.rmtree(path)  # this run's results only
        elif path.exists():
            path.unlink()


def _publish(s: DemoSettings, t0: float, report: dict, traces: dict) -> None:
    """Write ``report.json`` and ``traces.npz``, then print, save and plot from them.

    Raises StageError with the report's ``failure`` when it has one.
    """
    out = s.out
    atomic_write_text(out / "report.json", json.dumps(report, indent=2) + "\n")
    save_traces(out / "traces.npz", traces)
    # Everything shown comes from the files just written.
    report = json.loads((out / "report.json").read_text())
    text = report_text(report)
    print(text, flush=True)
    atomic_write_text(out / "report.txt", text + "\n")
    if s.plots:
        for path in plot_report(out, report, dict(np.load(out / "traces.npz"))):
            say(t0, f"plot written: {path}")
    if report["failure"]:
        raise StageError(report["failure"])


def _set_handlers(handlers: dict, previous: dict) -> None:
    """Install ``handlers`` (signal -> handler), leaving alone the signals whose
    ``previous`` handler was not installed from Python (None: it could not be restored)."""
    for sig, handler in handlers.items():
        if previous[sig] is not None:
            signal.signal(sig, handler)
