"""The paper's error measures (policy_align_ros.learning.metrics)."""

import numpy as np
import pytest

from policy_align_ros.learning import metrics


def test_potential_nmse_ignores_a_constant_offset():
    rng = np.random.default_rng(0)
    true = rng.normal(size=100)
    assert metrics.potential_nmse(true + 3.0, true) == pytest.approx(0.0, abs=1e-24)
    noisy = true + 0.1 * rng.normal(size=100)
    assert metrics.potential_nmse(noisy, true) == pytest.approx(0.01, rel=0.3)


def test_nupe_is_normalised_by_total_variance():
    rng = np.random.default_rng(1)
    pi = rng.normal(size=(500, 3))
    assert metrics.nupe(pi, pi) == 0.0
    assert metrics.nupe(pi, np.zeros_like(pi)) == pytest.approx(
        np.mean(np.sum(pi**2, 1)) / np.sum(np.var(pi, 0))
    )


def test_ncpe_ignores_errors_the_constraint_removes():
    rng = np.random.default_rng(2)
    pi = rng.normal(size=(200, 2))
    N = np.tile(np.diag([1.0, 0.0]), (200, 1, 1))  # motion along x1 only
    wrong_in_x2 = pi + np.array([0.0, 5.0])
    assert metrics.ncpe(pi, wrong_in_x2, N) == pytest.approx(0.0, abs=1e-12)
    assert metrics.ncpe(pi, pi + np.array([1.0, 0.0]), N) > 0.5


def test_shape_errors():
    with pytest.raises(ValueError, match=r"\(3, 2\).*\(3, 3\)"):
        metrics.nupe(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"^N\b.*\(3, 2, 2\).*\(3, 2\)"):
        metrics.ncpe(np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 2)))
