"""``policy-align bench suite`` (policy_align_ros.experiments.suite)."""

import argparse
import json

import numpy as np
import pytest

from policy_align_ros.cli import main
from policy_align_ros.experiments import suite
from policy_align_ros.experiments.suite_cases import CASES


def test_suite_reports_both_models_and_the_cv_check(tmp_path, capsys, monkeypatch):
    tasks = []
    run_case = suite.run_case

    def spy(task):
        tasks.append(task)
        return run_case(task)

    monkeypatch.setattr(suite, "run_case", spy)
    args = ["bench", "suite", "--cases", "quad_iso_2", "--datasets", "1", "--jobs", "1",
            "--seed", "3", "--set", "n_centres=50", "--demos", "12",
            "--max-extrapolation-rad", "0.8", "--out", str(tmp_path)]
    assert main(args) == 0
    # The settings reach the case: seed 3, n_centres=50, no noise, 12 demonstrations, the
    # guarded runs' cap.
    assert tasks == [("quad_iso_2", 3, {"n_centres": 50}, 0.0, 12, 0.8)]
    table = (tmp_path / "suite.md").read_text()
    assert "| quad_iso_2 | 2 | 50 Hz | previous |" in table
    assert "| quad_iso_2 | 2 | 50 Hz | new |" in table
    assert (tmp_path / "suite.png").stat().st_size > 0
    (result,) = json.loads((tmp_path / "suite.json").read_text())
    assert result["n_train"] == 12
    new = result["models"]["new"]
    # A 2-D quadratic from new starts: the new model must be accurate and settle at the goal.
    assert new["demo_nupe"] < 0.05 and new["free_rel_max"] < 0.05
    # Under the executor's guard, capped at 0.8 rad, every free run still reaches the goal.
    assert result["guard_rad"] == 0.8
    assert new["free_outcomes"] == [suite.N_ROLLOUTS, 0, 0, 0]
    # Exact data from one potential: the CV folds agree on where every run stops.
    assert new["free_reached_flagged"] == new["unseen_reached_flagged"] == 0
    assert "free_outcomes" not in result["models"]["previous"]
    assert result["cv"]["best_candidate_nupe"] <= result["cv"]["picked_nupe"]
    assert result["cv"]["pick_within_20pct"] == (
        result["cv"]["picked_nupe"] <= 1.2 * result["cv"]["best_candidate_nupe"])
    assert result["cv"]["picked_candidate"]["offset_ridge"] == result["chosen"]["offset_ridge"]
    assert table.strip() in capsys.readouterr().out  # prints the table it writes


@pytest.mark.parametrize("bad", [["--cases", "nope"], ["--set", "bogus=1"],
                                 ["--noise", "-1"], ["--demos", "1"],
                                 ["--max-extrapolation-rad", "0"],
                                 ["--max-extrapolation-rad", "nan"],
                                 ["--max-extrapolation-rad", "inf"]])
def test_suite_rejects_unknown_cases_and_settings(tmp_path, bad):
    assert main(["bench", "suite", *bad, "--out", str(tmp_path)]) == 2
    assert list(tmp_path.iterdir()) == []
    args = argparse.Namespace(cases=None, datasets=1, seed=0, set=None, noise=0.0,
                              demos=None, max_extrapolation_rad=None, jobs=1,
                              out=str(tmp_path))
    option, value = bad[0].lstrip("-").replace("-", "_"), bad[1]
    setattr(args, option, value if option in ("cases", "noise") else
            [value] if option == "set" else
            float(value) if option == "max_extrapolation_rad" else int(value))
    with pytest.raises(ValueError):
        suite.main(args)
    assert list(tmp_path.iterdir()) == []


def test_suite_noise_has_the_requested_size_and_spares_the_velocities():
    rng = np.random.default_rng(0)
    problem = CASES["quad_aniso_3"].make(rng)
    demos = suite._demos(problem, problem.sample_starts(rng, 5), rng)
    noisy = suite._with_noise(demos, 0.5, seed=0)
    clean = [d.trajectory for d in demos]
    steps = np.concatenate([np.linalg.norm(np.diff(t.positions, axis=0), axis=1)
                            for t in clean])
    pairs = list(zip(noisy, clean, strict=True))
    added = np.concatenate([n.positions - c.positions for n, c in pairs])
    rms_norm = np.sqrt(np.mean(np.sum(added**2, axis=1)))
    assert rms_norm == pytest.approx(0.5 * np.median(steps), rel=0.05)
    assert all(np.array_equal(n.velocities, c.velocities) for n, c in pairs)
    assert suite._with_noise(demos, 0.0, seed=0)[0] is clean[0]
