"""Tests of the local-linear regression's model-file state (round trips, older formats)."""

import io
import json

import numpy as np
import pytest

from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression


def test_state_round_trip_is_exact_and_pickle_free(toy, toy_model):
    arrays, meta = toy_model.get_state()
    meta = json.loads(json.dumps(meta))
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    with np.load(buffer, allow_pickle=False) as data:
        loaded = {k: data[k] for k in data.files}
    model = LocalLinearRegression.from_state(loaded, meta)
    assert {"floors", "softness"} <= set(loaded)
    X = np.vstack([toy[0], [[40.0, -7.0]]])
    np.testing.assert_array_equal(model.predict(X), toy_model.predict(X))
    np.testing.assert_array_equal(model.gradient(X), toy_model.gradient(X))
    assert model.bandwidth_ == toy_model.bandwidth_
    assert model.cv_scores_ == toy_model.cv_scores_
    assert model.get_params() == {**toy_model.get_params(), "random_state": 0}


def test_state_with_the_removed_increment_weight_still_loads(toy, toy_model):
    # Model files written before the derivative equations were removed name the parameter.
    arrays, meta = toy_model.get_state()
    old = {**meta, "params": {**meta["params"], "increment_weight": 0.0}}
    model = LocalLinearRegression.from_state(arrays, json.loads(json.dumps(old)))
    assert "increment_weight" not in model.get_params()
    X = np.vstack([toy[0][:50], [[40.0, -7.0]]])
    np.testing.assert_array_equal(model.gradient(X), toy_model.gradient(X))
    with pytest.raises(TypeError):
        LocalLinearRegression(increment_weight=0.5)


def test_state_with_the_removed_smoothing_still_loads(toy, toy_model):
    # Model files written before the neighbour smoothing of the slopes was removed name it.
    arrays, meta = toy_model.get_state()
    X = np.vstack([toy[0][:50], [[40.0, -7.0]]])
    for value in (0.0, None):
        old = {**meta, "params": {**meta["params"], "smoothing": value}}
        model = LocalLinearRegression.from_state(arrays, json.loads(json.dumps(old)))
        assert "smoothing" not in model.get_params()
        np.testing.assert_array_equal(model.gradient(X), toy_model.gradient(X))
    with pytest.raises(TypeError):
        LocalLinearRegression(smoothing=2.0)


def test_from_state_rejects_bad_state(toy_model):
    arrays, meta = toy_model.get_state()
    with pytest.raises(ValueError, match=r"\b99\b"):
        LocalLinearRegression.from_state(arrays, {**meta, "version": 99})
    with pytest.raises(ValueError, match="slopes"):
        LocalLinearRegression.from_state({**arrays, "slopes": arrays["slopes"][:-1]}, meta)
    with pytest.raises(ValueError, match="intercepts.*slopes.*origin"):
        LocalLinearRegression.from_state({"centers": arrays["centers"]}, meta)
    with pytest.raises(ValueError, match="floors.*softness"):
        LocalLinearRegression.from_state({k: v for k, v in arrays.items() if k != "floors"}, meta)
    with pytest.raises(ValueError, match="softness"):
        LocalLinearRegression.from_state({**arrays, "softness": -arrays["softness"]}, meta)


def test_version_1_state_loads_as_linear_models(toy, toy_model):
    arrays, meta = toy_model.get_state()
    old = {k: v for k, v in arrays.items() if k not in ("floors", "softness")}
    params = {k: v for k, v in meta["params"].items() if k != "extrapolation"}
    model = LocalLinearRegression.from_state(old, {**meta, "version": 1, "params": params})
    assert model.floors_ is None
    linear = LocalLinearRegression(extrapolation="linear", random_state=0)
    linear.fit(toy[0][~toy[3]], toy[1][~toy[3]], groups=toy[2][~toy[3]])
    np.testing.assert_allclose(model.predict(toy[0]), linear.predict(toy[0]), atol=1e-12)


def test_state_round_trip_with_adaptive_widths(toy):
    X, y, g, _ = toy
    reg = LocalLinearRegression(widths="adaptive", random_state=4).fit(X, y, groups=g)
    arrays, meta = reg.get_state()
    assert arrays["widths"].shape == (len(reg.centers_),)
    model = LocalLinearRegression.from_state(arrays, json.loads(json.dumps(meta)))
    np.testing.assert_array_equal(model.widths_, reg.widths_)
    Q = np.vstack([X[:50], [[40.0, -7.0]]])
    np.testing.assert_array_equal(model.gradient(Q), reg.gradient(Q))
    with pytest.raises(ValueError, match="widths"):
        LocalLinearRegression.from_state({**arrays, "widths": arrays["widths"][:-1]}, meta)
    with pytest.raises(ValueError, match="widths"):
        LocalLinearRegression.from_state({**arrays, "widths": -arrays["widths"]}, meta)


def test_version_2_state_loads_with_the_global_width(toy):
    X, y, g, _ = toy
    reg = LocalLinearRegression(widths="global", random_state=0).fit(X, y, groups=g)
    arrays, meta = reg.get_state()
    assert "widths" not in arrays
    params = {k: v for k, v in meta["params"].items() if k != "widths"}
    model = LocalLinearRegression.from_state(arrays, {**meta, "version": 2, "params": params})
    assert model.widths_ is None and model.widths == "cv"
    np.testing.assert_array_equal(model.predict(X), reg.predict(X))
