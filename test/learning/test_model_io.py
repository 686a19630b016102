"""Model files (policy_align_ros.learning.model_io and PolicyAlign.save/load)."""

import copy
import errno
import json
import math
import os
import stat
import zipfile

import numpy as np
import pytest

from policy_align_ros.experiments.toy import make_toy_dataset
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.model_io import (
    FORMAT_VERSION,
    atomic_write_bytes,
    atomic_write_text,
    json_float,
    json_floats,
    load_npz,
    save_npz,
)
from policy_align_ros.learning.policy_file import model_robot_fields, read_robot_fields


@pytest.fixture(scope="module")
def model():
    data = make_toy_dataset("sinusoid", 20, 25, np.random.default_rng(0))
    return PolicyAlign(sigma="medium").fit(data.trajectories, joint_names=["j1", "j2"])


def test_round_trip_is_exact_and_leaves_no_temporary_files(model, tmp_path):
    path = model.save(tmp_path / "model.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz"]
    loaded = PolicyAlign.load(path)
    X = np.random.default_rng(1).uniform(-2, 2, size=(30, 2))
    np.testing.assert_array_equal(loaded.potential(X), model.potential(X))
    np.testing.assert_array_equal(loaded.policy(X), model.policy(X))
    assert loaded.joint_names_ == ["j1", "j2"]
    assert loaded.sigma2_ == model.sigma2_
    np.testing.assert_array_equal(loaded.inliers_, model.inliers_)
    for a, b in zip(loaded.aligned_potentials_, model.aligned_potentials_, strict=True):
        np.testing.assert_array_equal(a, b)
    with np.load(path, allow_pickle=False) as raw:  # numeric arrays and a JSON header only
        assert all(raw[name].dtype != object for name in raw.files)


def test_truncated_file_names_the_file(model, tmp_path):
    path = model.save(tmp_path / "model.npz")
    data = path.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cut.npz"):
        PolicyAlign.load(cut)


def test_foreign_and_missing_files(tmp_path):
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.arange(3))
    with pytest.raises(ValueError, match="foreign.npz"):
        PolicyAlign.load(foreign)
    text = tmp_path / "notes.npz"
    text.write_text("hello")
    with pytest.raises(ValueError, match="notes.npz"):
        PolicyAlign.load(text)
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        PolicyAlign.load(tmp_path / "missing.npz")


def test_newer_format_version_is_refused(tmp_path):
    path = save_npz(tmp_path / "future.npz", {"kind": "policy_align"}, {"x": np.zeros(2)})
    with zipfile.ZipFile(path) as zf:
        assert "__header__.npy" in zf.namelist()
    newer = tmp_path / "newer.npz"
    np.savez(newer, __header__=np.array(json.dumps(
        {"format_version": FORMAT_VERSION + 1, "kind": "policy_align"})))
    with pytest.raises(ValueError, match=rf"newer.npz.*\b{FORMAT_VERSION + 1}\b"):
        load_npz(newer, kind="policy_align")


def test_object_arrays_are_refused(tmp_path):
    with pytest.raises(ValueError, match="'bad'"):
        save_npz(tmp_path / "bad.npz", {"kind": "x"}, {"bad": np.array([{}], dtype=object)})
    assert not list(tmp_path.iterdir())


def test_bytes_that_are_no_archive_are_not_called_a_pickle(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"junk")
    with pytest.raises(ValueError, match="junk.npz") as err:
        load_npz(junk, "policy_align")
    assert "pickle" not in str(err.value)


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_model_file_mode_follows_the_umask(model, tmp_path, umask):
    old = os.umask(umask)
    try:
        path = model.save(tmp_path / "model.npz")
        text = atomic_write_text(tmp_path / "report.txt", "x\n")
    finally:
        os.umask(old)
    for written in (path, text):
        assert stat.S_IMODE(written.stat().st_mode) == 0o666 & ~umask, oct(umask)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz", "report.txt"]


def test_failed_write_removes_its_temporary_file_and_keeps_the_old_model(model, tmp_path):
    path = model.save(tmp_path / "model.npz")
    before = path.read_bytes()

    def failing(fh):
        fh.write(b"partial")
        raise OSError(errno.EFBIG, "File too large")

    with pytest.raises(OSError) as err:
        atomic_write_bytes(path, failing)
    assert err.value.errno == errno.EFBIG
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["model.npz"]


def test_state_definition_round_trips_and_old_files_load_as_joint_states(model, tmp_path):
    definition = {"type": "frames", "robot": "talos", "joints": ["a", "b"],
                  "frames": ["hand"], "root_frame": "universe", "locked_posture": {},
                  "urdf_sha256": "0" * 64, "rest": {"a": 0.1, "b": -0.2}}
    assert model.state_definition_ is None
    plain = PolicyAlign.load(model.save(tmp_path / "joints.npz"))
    assert plain.state_definition_ is None
    model.state_definition_ = definition
    try:
        path = model.save(tmp_path / "frames.npz")
    finally:
        model.state_definition_ = None
    loaded = PolicyAlign.load(path)
    assert loaded.state_definition_ == definition
    header, _ = load_npz(path, "policy_align")
    assert header["state"] == "frame positions" and header["state_definition"] == definition
    # A file written before state definitions existed (no such header key) still loads.
    header, arrays = load_npz(tmp_path / "joints.npz", "policy_align")
    del header["state_definition"]
    header.pop("format_version")
    old = save_npz(tmp_path / "old.npz", header, arrays)
    assert PolicyAlign.load(old).state_definition_ is None
    # A definition that is not a dict is refused on save and on load.
    model.state_definition_ = "frames:hand"
    try:
        with pytest.raises(ValueError, match="state_definition_"):
            model.save(tmp_path / "bad.npz")
    finally:
        model.state_definition_ = None
    header["state_definition"] = ["hand"]
    bad = save_npz(tmp_path / "bad.npz", header, arrays)
    with pytest.raises(ValueError, match=r"bad.npz.*\bstate_definition\b"):
        PolicyAlign.load(bad)


def _toy_trajectories():
    return make_toy_dataset("sinusoid", 10, 25, np.random.default_rng(3)).trajectories


def test_numpy_scalar_and_generator_parameters_save_and_load(tmp_path):
    from policy_align_ros.learning.regressors import TrendKernelRegression

    trajs = _toy_trajectories()
    X = np.random.default_rng(1).uniform(-2, 2, size=(20, 2))
    regressor = TrendKernelRegression(n_centres=np.int64(50),
                                      random_state=np.random.default_rng(1))
    model = PolicyAlign(random_state=np.int64(3), sigma=np.float32(0.05),
                        weight_tol=np.float32(1e-12), regressor=regressor).fit(trajs)
    loaded = PolicyAlign.load(model.save(tmp_path / "numpy.npz"))
    np.testing.assert_array_equal(loaded.policy(X), model.policy(X))
    params = loaded.get_params()
    assert params["random_state"] == 3 and type(params["random_state"]) is int
    assert type(params["sigma"]) is float and params["sigma"] == float(np.float32(0.05))
    reg_params = loaded.regressor_.get_params()
    assert reg_params["n_centres"] == 50 and type(reg_params["n_centres"]) is int
    assert reg_params["random_state"] is None  # a Generator's state is not saved
    # get_params keeps the user's values as given (scikit-learn convention).
    assert type(model.get_params()["random_state"]) is np.int64
    assert isinstance(model.regressor_.get_params()["random_state"], np.random.Generator)
    # A Generator as the estimator's own random_state is saved as None too.
    seeded = PolicyAlign(random_state=np.random.default_rng(2)).fit(trajs)
    assert PolicyAlign.load(seeded.save(tmp_path / "gen.npz")).random_state is None


def test_a_field_json_cannot_hold_is_named(model, tmp_path):
    import copy

    broken = copy.copy(model)
    broken.state_definition_ = {"rest": np.zeros(2)}
    with pytest.raises(ValueError, match=r"state_definition\.rest.*ndarray"):
        broken.save(tmp_path / "bad.npz")
    assert not list(tmp_path.iterdir())


def _rewrite(tmp_path, source, header=None, arrays=None):
    """``source``'s model file with its header and arrays replaced, as ``bad.npz``."""
    old_header, old_arrays = load_npz(source, "policy_align")
    path = tmp_path / "bad.npz"
    np.savez(path, __header__=np.array(json.dumps(
        old_header if header is None else header(dict(old_header)))),
             **(old_arrays if arrays is None else arrays(dict(old_arrays))))
    return path


def _set(mapping, key, value):
    mapping[key] = value
    return mapping


@pytest.mark.parametrize(("header", "arrays", "message"), [
    # The file, the field and the numbers that disagree.
    (lambda h: [1, 2], None, r"\blist\b"),
    (lambda h: _set(h, "training", [1]), None, r"\btraining\b"),
    (lambda h: _set(h, "params", [1]), None, r"\bparams\b"),
    (lambda h: _set(h, "format_version", "1"), None, r"format_version\b.*'1'"),
    (lambda h: _set(h, "n_features", 3), None, r"\b2\b.*n_features\b.*\b3\b"),
    (None, lambda a: _set(a, "aligned_lengths", np.array([5])), r"aligned_lengths'.*\b1\b"),
    (None, lambda a: _set(a, "inliers", np.array([0, 99])), r"\binliers\b.*\b20\b"),
    (None, lambda a: _set(a, "groups", np.zeros(3, dtype=int)), r"groups'.*\b3\b"),
    (None, lambda a: _set(a, "support_states", np.zeros((4, 3))),
     r"support_states\b.*\b3\b.*n_features\b.*\b2\b"),
    (lambda h: _set(h, "folds", {"class": "x"}), None, r"\bfolds\b.*\barray\b"),
    (lambda h: _set(h, "folds", [1]), None, r"\bfolds\[0\].*\bobject\b"),
    # A fold model named in the header whose arrays are missing.
    (None, lambda a: {k: v for k, v in a.items() if not k.startswith("fold1.")},
     r"malformed"),
])
def test_malformed_model_files_name_the_file_and_the_problem(model, tmp_path, header,
                                                             arrays, message):
    good = model.save(tmp_path / "good.npz")
    bad = _rewrite(tmp_path, good, header, arrays)
    with pytest.raises(ValueError, match=f"bad.npz.*{message}"):
        PolicyAlign.load(bad)


def test_euler_scale_and_position_noise_survive_save_and_load(tmp_path):
    from policy_align_ros.sim.demonstrations import rollout
    from policy_align_ros.sim.experts import QuadraticPotential

    # Held-command demonstrations with velocities of an isotropic quadratic: "auto"
    # trusts the velocities and rescales the Euler potentials (euler_scale_ != 1).
    rng = np.random.default_rng(8)
    pot = QuadraticPotential([0.3, -0.2, 0.1], 0.5 * np.eye(3))
    rows = rng.standard_normal((8, 1, 3))  # one constraint row per demonstration
    demos = [rollout(rng.uniform(-1, 1, 3), pot, lambda x, t, pi, r=r: r, 40,
                     0.05).trajectory for r in rows]
    model = PolicyAlign(random_state=0).fit(demos)
    assert model.euler_scale_ != 1.0
    loaded = PolicyAlign.load(model.save(tmp_path / "a.npz"))
    assert loaded.euler_scale_ == model.euler_scale_
    assert loaded.position_noise_ == model.position_noise_
    again = PolicyAlign.load(loaded.save(tmp_path / "b.npz"))
    assert (again.euler_scale_, again.position_noise_) == (model.euler_scale_,
                                                           model.position_noise_)
    # Files without the exact header values use the training summary, then the defaults.
    header, arrays = load_npz(tmp_path / "a.npz", "policy_align")
    del header["euler_scale"], header["position_noise"]
    older = PolicyAlign.load(save_npz(tmp_path / "older.npz", header, arrays))
    assert older.euler_scale_ == model.euler_scale_
    assert older.position_noise_ == pytest.approx(model.position_noise_, rel=1e-12)
    del header["training"]["euler_scale"], header["training"]["position_noise_rms"]
    oldest = PolicyAlign.load(save_npz(tmp_path / "oldest.npz", header, arrays))
    assert (oldest.euler_scale_, oldest.position_noise_) == (1.0, 0.0)


def test_json_float_writes_non_finite_values_as_each_format_holds_them():
    assert json_float(np.float64(0.5)) == 0.5 and type(json_float(np.float64(0.5))) is float
    assert type(json_float(np.int64(3))) is int and json_float(np.bool_(True)) is True
    assert json_float(None) is None
    # Model headers: strings that float() reads back.
    assert [json_float(v, "string") for v in (math.inf, -math.inf, math.nan, 2.0)] == [
        "inf", "-inf", "nan", 2.0]
    # Reports: null.
    assert json_float(np.float64(math.inf), "null") is None
    assert json_float(math.nan, "null") is None
    # As json.dumps(default=...): NumPy scalars only, anything else is a TypeError.
    assert json.dumps({"a": np.float32(0.5), "b": np.int64(2)}, default=json_float) == (
        '{"a": 0.5, "b": 2}')
    with pytest.raises(TypeError, match="'object'"):
        json.dumps({"a": object()}, default=json_float)
    with pytest.raises(ValueError, match="nonfinite"):
        json_float(math.inf, "zero")


def test_the_robot_field_round_trips_and_is_read_from_the_header_alone(model, tmp_path):
    assert model.robot_ is None  # a plain fit knows no robot
    named = copy.copy(model)
    named.robot_ = "panda"
    path = named.save(tmp_path / "model.npz")
    assert PolicyAlign.load(path).robot_ == "panda"
    assert read_robot_fields(path) == ("panda", ["j1", "j2"])
    assert model_robot_fields(PolicyAlign.load(path)) == ("panda", ["j1", "j2"])
    # A frames state names its robot and joints in its definition.
    framed = copy.copy(model)
    framed.state_definition_ = {"type": "frames", "robot": "talos", "joints": ["a", "b"]}
    path = framed.save(tmp_path / "frames.npz")
    assert read_robot_fields(path) == ("talos", ["a", "b"])
    assert model_robot_fields(PolicyAlign.load(path)) == ("talos", ["a", "b"])
    named.robot_ = 7
    with pytest.raises(ValueError, match="robot_"):
        named.save(tmp_path / "bad.npz")


def test_an_old_file_without_the_robot_field_still_loads(model, tmp_path):
    source = model.save(tmp_path / "model.npz")
    old = _rewrite(tmp_path, source, header=lambda h: {k: v for k, v in h.items()
                                                       if k != "robot"})
    assert "robot" not in load_npz(old, "policy_align")[0]
    loaded = PolicyAlign.load(old)
    assert loaded.robot_ is None and loaded.joint_names_ == ["j1", "j2"]
    X = np.random.default_rng(1).uniform(-2, 2, size=(5, 2))
    np.testing.assert_array_equal(loaded.policy(X), model.policy(X))
    assert read_robot_fields(old) == (None, ["j1", "j2"])
    assert model_robot_fields(loaded) == (None, ["j1", "j2"])
    bad = _rewrite(tmp_path, source, header=lambda h: _set(h, "robot", ["panda"]))
    with pytest.raises(ValueError, match=r"bad.npz.*\brobot\b"):
        PolicyAlign.load(bad)


def test_fold_models_round_trip_and_old_files_load_without_them(model, tmp_path):
    assert len(model.fold_regressors_) >= 2
    source = model.save(tmp_path / "model.npz")
    loaded = PolicyAlign.load(source)
    X = np.random.default_rng(2).uniform(-2, 2, size=(7, 2))
    assert len(loaded.fold_regressors_) == len(model.fold_regressors_)
    for mine, theirs in zip(model.fold_regressors_, loaded.fold_regressors_, strict=True):
        np.testing.assert_array_equal(theirs.gradient(X), mine.gradient(X))
    # Not the model's own regressor: each fold model was fitted without some data.
    assert not np.allclose(loaded.fold_regressors_[0].gradient(X), loaded.policy(X) * -1)
    old = _rewrite(tmp_path, source,
                   header=lambda h: {k: v for k, v in h.items() if k != "folds"},
                   arrays=lambda a: {k: v for k, v in a.items() if not k.startswith("fold")})
    assert PolicyAlign.load(old).fold_regressors_ == []


def test_json_floats_makes_non_finite_floats_null_in_nested_dicts():
    value = {"a": np.float64(math.inf), "b": {"c": math.nan, "d": 0.5}, "e": 3, "f": None}
    assert json_floats(value) == {"a": None, "b": {"c": None, "d": 0.5}, "e": 3, "f": None}
    assert type(json_floats(np.float64(0.5))) is float and json_floats("x") == "x"
