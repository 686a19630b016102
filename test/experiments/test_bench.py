"""``policy-align bench`` wiring and the Table I runner (policy_align_ros.experiments.bench)."""

import json

import numpy as np
import pytest

from policy_align_ros.cli import main
from policy_align_ros.experiments import suite
from policy_align_ros.experiments.scale import _child, make_scale_dataset


def test_toy_bench_writes_table_raw_numbers_and_figure(tmp_path, capsys):
    assert main(["bench", "toy", "--datasets", "1", "--jobs", "1", "--out", str(tmp_path)]) == 0
    table = (tmp_path / "toy.md").read_text()
    assert table.count("| ours |") == 9 and table.count("| paper |") == 9
    raw = json.loads((tmp_path / "toy.json").read_text())
    assert set(raw) == {f"{p}_K{k}_{r}" for p, k in [("parabola", 40), ("sinusoid", 40),
                                                      ("sinusoid", 100)]
                        for r in ("narrow", "medium", "wide")}
    assert all(np.isfinite(v[0]["nupe"]) for v in raw.values())
    assert (tmp_path / "toy.png").stat().st_size > 10_000
    assert "Table I reproduction" in capsys.readouterr().out


def test_bad_bench_arguments_exit_2_with_a_message(tmp_path, capsys):
    assert main(["bench", "toy", "--jobs", "0", "--out", str(tmp_path)]) == 2
    assert "--jobs must be at least 1" in capsys.readouterr().err


def test_scale_data_and_child_report():
    trajs = make_scale_dataset(6, 30, np.random.default_rng(0), dim=5)
    assert len(trajs) == 6 and trajs[0].positions.shape == (30, 5)
    assert trajs[0].times[1] == 100.0 / 30
    report = _child(20, 40, seed=0)
    assert report["K"] == 20 and report["peak_mb"] > 0
    assert report["alignment_nmse"] < 0.05


def test_suite_reports_both_models_and_the_cv_check(tmp_path, capsys):
    args = ["bench", "suite", "--cases", "quad_iso_2", "--datasets", "1", "--jobs", "1",
            "--seed", "3", "--set", "n_centres=50", "--demos", "12", "--out", str(tmp_path)]
    assert main(args) == 0
    table = (tmp_path / "suite.md").read_text()
    assert "| quad_iso_2 | 2 | 50 Hz | previous |" in table
    assert "| quad_iso_2 | 2 | 50 Hz | new |" in table
    assert "n_centres=50" in table and "CV pick within 20 %" in table
    assert "12 training demonstrations per data set" in table
    assert (tmp_path / "suite.png").stat().st_size > 0
    (result,) = json.loads((tmp_path / "suite.json").read_text())
    assert result["n_train"] == 12
    new = result["models"]["new"]
    # A 2-D quadratic from new starts: the new model must be accurate and settle at the goal.
    assert new["demo_nupe"] < 0.05 and new["free_rel_max"] < 0.05
    assert result["cv"]["best_candidate_nupe"] <= result["cv"]["picked_nupe"]
    assert result["cv"]["picked_candidate"]["offset_ridge"] == result["chosen"]["offset_ridge"]
    assert "suite" in capsys.readouterr().out.lower()


def test_suite_rejects_unknown_cases_and_settings(tmp_path, capsys):
    assert main(["bench", "suite", "--cases", "nope", "--out", str(tmp_path)]) == 2
    assert "unknown suite case" in capsys.readouterr().err
    assert main(["bench", "suite", "--set", "bogus=1", "--out", str(tmp_path)]) == 2
    assert "expected NAME=VALUE" in capsys.readouterr().err
    assert main(["bench", "suite", "--noise", "-1", "--out", str(tmp_path)]) == 2
    assert "--noise" in capsys.readouterr().err
    assert main(["bench", "suite", "--demos", "1", "--out", str(tmp_path)]) == 2
    assert "--demos" in capsys.readouterr().err


def test_suite_noise_has_the_requested_size_and_spares_the_velocities():
    rng = np.random.default_rng(0)
    problem = suite.CASES["quad_aniso_3"].make(rng)
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
