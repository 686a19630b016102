"""A short end-to-end run of ``policy-align demo`` (separate node processes, domain 220)."""

import argparse
import os
from pathlib import Path

from policy_align_ros.data import load_dataset
from policy_align_ros.client.demo import run_demo


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


def test_short_demo_runs_every_stage_and_cleans_up(tmp_path, capsys):
    out = tmp_path / "demo"
    args = argparse.Namespace(robot="talos", out=str(out), demos=3, demo_duration_s=1.0,
                              run_duration_s=1.5, domain_id=220, require_progress=False)
    code = run_demo(args)
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "demonstrator finished: 3 demonstrations recorded" in printed.out
    report = (out / "report.txt").read_text()
    for item in ("demonstrations: 3 recorded", "fit time", "held-out nCPE",
                 "(a) unconstrained", "(b) unseen constraint", "held hand moved"):
        assert item in report
    trajs, names, _ = load_dataset([out / "demos"])
    assert len(trajs) == 3 and len(names) == 18
    assert (out / "model.npz").is_file()
    assert (out / "demo_distance.png").stat().st_size > 0
    assert (out / "demo_hands.png").stat().st_size > 0
    assert _processes_mentioning(str(out / "params.yaml")) == []
