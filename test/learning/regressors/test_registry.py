"""The regressor protocol and registry (learning.regressors.protocol, .registry)."""

import numpy as np
import pytest

from policy_align_ros.learning.regressors import (
    REGISTRY,
    LocalLinearRegression,
    Regressor,
    TrendKernelRegression,
    register,
    regressor_class,
    takes_free_groups,
)


def test_the_built_in_regressors_are_registered_and_follow_the_protocol():
    assert REGISTRY["TrendKernelRegression"] is TrendKernelRegression
    assert REGISTRY["LocalLinearRegression"] is LocalLinearRegression
    for cls in REGISTRY.values():
        assert isinstance(cls(), Regressor)
        assert regressor_class(cls.__name__) is cls
    assert not isinstance(object(), Regressor)


def test_regressor_class_names_the_known_ones():
    with pytest.raises(ValueError, match="'Nope'.*TrendKernelRegression"):
        regressor_class("Nope")


def test_register_refuses_a_class_without_the_protocol():
    class NoGradient:
        def fit(self, X, y, groups=None):
            return self

        def predict(self, X):
            return np.zeros(len(X))

    with pytest.raises(ValueError, match="NoGradient.*'gradient'"):
        register(NoGradient)
    assert "NoGradient" not in REGISTRY


def test_takes_free_groups():
    assert takes_free_groups(TrendKernelRegression())
    assert not takes_free_groups(LocalLinearRegression())
