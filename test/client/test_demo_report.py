"""The demo's report: targets, report.json's fields, the printed report (no ROS graph)."""

import json
from types import SimpleNamespace

import numpy as np

from policy_align_ros.client.demo.report import (
    build_report,
    report_text,
    target_word,
    targets,
)
from policy_align_ros.client.demo.settings import DemoSettings


def _report():
    run = {"name": "unconstrained", "id": "unconstrained_1", "start": "new",
           "start_distance": 1.0, "final_distance": 0.04, "expert_final_distance": 0.001,
           "constraint": None, "held_frame_drift_mm": None}
    held = {**run, "name": "unseen_constraint", "id": "unseen_constraint_1",
            "final_distance": 0.06, "constraint": [{"type": "position", "frame": "f"}],
            "held_frame": "f", "held_frame_drift_mm": 1.5}
    return {"robot": "talos", "state": "joints",
            "demonstrations": {"recorded": 5, "training": 4, "held_out": 1, "discarded": 0},
            "sigma2": 0.05, "fit_time_s": 1.0, "heldout_ncpe_fresh": 0.3,
            "runs": [run, held], "total_time_s": 10.0}


def test_targets_and_report_text_follow_the_numbers():
    report = _report()
    status = targets(report)
    assert status == {"heldout_ncpe_fresh <= 0.2": False,
                      "unconstrained_1: final <= 10% of start and <= 0.05 rad": True,
                      "unseen_constraint_1: final <= expert + 0.05 rad": False,
                      "unseen_constraint_1: held frame drift <= 1 mm": False}
    text = report_text({**report, "targets": status})
    # Every run and every target of the report is shown, each target once.
    for run in report["runs"]:
        assert run["id"] in text
    for key in status:
        assert text.count(key) == 1
    # The text is made from the numbers: another final distance, another text.
    other = _report()
    other["runs"][0]["final_distance"] = 0.5
    assert report_text({**other, "targets": status}) != text
    assert report_text({**report, "targets": status}) == text


def test_report_fails_an_unconstrained_run_that_made_no_progress():
    task = SimpleNamespace(state_spec="joints", goal=np.zeros(2))
    learnt = {"demonstrations": {"recorded": 5}, "sigma2": 0.05, "fit_time_s": 1.23456,
              "heldout_ncpe_observed": None, "summary_source": "model header"}
    runs = _report()["runs"]
    report = build_report(DemoSettings(), task, learnt, 0.1, runs, sim={})
    assert report["failure"] == "" and report["fit_time_s"] == 1.235
    assert report["targets"] == targets(report)
    stuck = [{**runs[0], "final_distance": 1.0}, runs[1]]
    report = build_report(DemoSettings(), task, learnt, 0.1, stuck, sim={})
    assert "unconstrained_1" in report["failure"]
    lenient = build_report(DemoSettings(require_progress=False), task, learnt, 0.1, stuck,
                           sim={})
    assert lenient["failure"] == ""


def test_a_constrained_run_without_a_held_frame_reads_not_measured():
    # A constraint that holds no frame (e.g. a joint-space plane) leaves the drift None:
    # the drift target is not measured, never met, and the report is still written.
    report = _report()
    report["runs"][1].update(final_distance=0.01, held_frame_drift_mm=None,
                             constraint=[{"type": "plane", "normal": [1.0, 0.0]}])
    del report["runs"][1]["held_frame"]
    status = targets(report)
    assert status["unseen_constraint_1: final <= expert + 0.05 rad"] is True
    assert status["unseen_constraint_1: held frame drift <= 1 mm"] is None
    assert target_word(status["unseen_constraint_1: held frame drift <= 1 mm"]) \
        == "not measured"
    assert target_word(True) == "met" and target_word(False) == "MISSED"
    assert report_text({**report, "targets": status}).count("not measured") == 1

    task = SimpleNamespace(state_spec="joints", goal=np.zeros(2))
    learnt = {"demonstrations": {"recorded": 5}, "sigma2": 0.05, "fit_time_s": 1.0,
              "heldout_ncpe_observed": None, "summary_source": "model header"}
    built = build_report(DemoSettings(robot="panda"), task, learnt, 0.1, report["runs"],
                         sim={})
    assert built["failure"] == ""
    assert built["targets"]["unseen_constraint_1: held frame drift <= 1 mm"] is None
    assert not all(built["targets"].values())
    assert json.loads(json.dumps(built))["targets"] == built["targets"]
