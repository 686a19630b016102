"""The estimator contract (policy_align_ros.learning.base) and the estimators that follow it."""

import numpy as np
import pytest

from policy_align_ros.learning import NotFittedError, PolicyAlign
from policy_align_ros.learning.base import BaseEstimator, check_is_fitted
from policy_align_ros.learning.regressors import TrendKernelRegression


class _Inner(BaseEstimator):
    def __init__(self, width: float = 1.0, *, folds: int = 3) -> None:
        self.width = width
        self.folds = folds


class _Outer(BaseEstimator):
    def __init__(self, inner=None, tol: float = 1e-3) -> None:
        self.inner = inner
        self.tol = tol


def test_params_and_repr_come_from_the_signature():
    est = _Inner(2.0, folds=5)
    assert est.get_params() == {"width": 2.0, "folds": 5}
    assert repr(est) == "_Inner(width=2.0, folds=5)"
    assert est.set_params(width=3.0) is est
    assert est.width == 3.0 and est.get_params()["width"] == 3.0


def test_deep_params_reach_a_nested_estimator():
    outer = _Outer(_Inner(2.0), tol=0.1)
    assert outer.get_params(deep=False) == {"inner": outer.inner, "tol": 0.1}
    deep = outer.get_params()
    assert deep["inner__width"] == 2.0 and deep["inner__folds"] == 3
    outer.set_params(inner__folds=7, tol=0.2)
    assert outer.inner.folds == 7 and outer.tol == 0.2
    # The repr shows the constructor arguments only, the nested one by its own repr.
    assert repr(outer) == "_Outer(inner=_Inner(width=2.0, folds=7), tol=0.2)"


def test_unknown_or_unreachable_params_raise():
    with pytest.raises(ValueError, match="'depth'"):
        _Inner().set_params(depth=1)
    with pytest.raises(ValueError, match=r"'inner'.*\bNone\b"):
        _Outer(inner=None).set_params(inner__width=1.0)


def test_check_is_fitted():
    est = _Inner()
    with pytest.raises(NotFittedError):
        check_is_fitted(est, "coef_")
    est.coef_ = np.zeros(2)
    check_is_fitted(est, "coef_")
    assert issubclass(NotFittedError, ValueError)


def test_estimators_follow_the_contract():
    reg = TrendKernelRegression(n_folds=5)
    model = PolicyAlign("wide", regressor=reg)
    params = model.get_params()
    assert params["sigma"] == "wide" and params["regressor"] is reg
    assert params["regressor__n_folds"] == 5 and params["random_state"] == 0
    assert reg.get_params()["random_state"] == 0
    model.set_params(regressor__n_centres=50, merge_tol=0.2)
    assert reg.n_centres == 50 and model.merge_tol == 0.2
    assert repr(model).startswith("PolicyAlign(sigma='wide', integration='auto'")
    assert "n_centres=50" in repr(model)
    with pytest.raises(ValueError, match="'width'"):
        model.set_params(width=1.0)
    for est in (model, reg):
        with pytest.raises(NotFittedError):
            est.predict(np.zeros((1, 2))) if est is reg else est.policy(np.zeros((1, 2)))
