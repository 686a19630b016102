"""Kernel-width heuristics (policy_align_ros.learning.bandwidth)."""

import numpy as np
import pytest

from policy_align_ros.learning.bandwidth import (
    closest_approach_matrix,
    resolve_sigma2,
    sigma2_heuristics,
)


def _lines(offsets):
    """Parallel segments along x1 at heights ``offsets`` (x2)."""
    s = np.linspace(0.0, 1.0, 11)
    return [np.column_stack([s, np.full_like(s, h)]) for h in offsets]


def test_closest_approach_matches_brute_force():
    rng = np.random.default_rng(0)
    trajs = [rng.normal(size=(rng.integers(2, 25), 3)) for _ in range(6)]
    d = closest_approach_matrix(trajs)
    for k, a in enumerate(trajs):
        for j, b in enumerate(trajs):
            if k != j:
                assert d[k, j] == pytest.approx(((a[:, None] - b[None]) ** 2).sum(-1).min())
    assert np.all(np.isinf(np.diag(d)))


def test_heuristics_on_known_geometry():
    # Heights 0, 1, 3: nearest squared distances 1, 1, 4 -> narrow = 1;
    # pair distances 1, 9, 4 -> wide = 4; medium = sqrt(1 * 4) = 2.
    s2 = sigma2_heuristics(_lines([0.0, 1.0, 3.0]))
    assert s2["narrow"] == pytest.approx(1.0)
    assert s2["wide"] == pytest.approx(4.0)
    assert s2["medium"] == pytest.approx(2.0)


def test_thinning_keeps_large_sets_close_to_exact():
    rng = np.random.default_rng(3)
    trajs = [np.cumsum(rng.normal(scale=0.05, size=(400, 3)), axis=0) + rng.normal(size=3)
             for _ in range(30)]
    exact = sigma2_heuristics(trajs, max_points=10**9)
    thin = sigma2_heuristics(trajs, max_points=3000)
    assert thin["wide"] == pytest.approx(exact["wide"], rel=0.1)
    assert exact["narrow"] <= thin["narrow"] <= 3 * exact["narrow"] + 0.01


def test_resolve_rejects_bad_values():
    trajs = _lines([0.0, 1.0])
    assert resolve_sigma2(0.3, trajs) == 0.3
    for bad in ("tiny", -1.0, 0.0, float("nan")):
        with pytest.raises(ValueError, match="sigma"):
            resolve_sigma2(bad, trajs)
    with pytest.raises(ValueError, match=r"\b2\b"):
        sigma2_heuristics(trajs[:1])


def test_converging_trajectories_keep_narrow_width_at_sampling_resolution():
    # Every trajectory settles exactly at the origin: all closest approaches are 0.
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 1.0, 21)[:, None]
    trajs = [(1.0 - t) * rng.normal(size=2) for _ in range(5)]
    steps = [np.linalg.norm(np.diff(x, axis=0), axis=1).mean() for x in trajs]
    s2 = sigma2_heuristics(trajs)
    assert s2["narrow"] == pytest.approx(np.median(steps) ** 2 / 4.0)
    assert s2["narrow"] <= s2["medium"] <= s2["wide"]


def test_policy_align_fits_demonstrations_that_meet_at_the_attractor():
    from policy_align_ros.learning import PolicyAlign

    rng = np.random.default_rng(5)
    trajs = []
    for _ in range(8):
        x = [rng.uniform(-1.0, 1.0, size=2)]
        for _ in range(60):  # phi = ||x||^2 / 2, converged to the origin within float eps
            x.append(x[-1] * 0.5)
        trajs.append(np.array(x))
    model = PolicyAlign(sigma="narrow", random_state=0).fit(trajs)
    assert np.all(np.isfinite(model.offsets_))
    assert len(model.inliers_) == len(trajs)


@pytest.mark.parametrize("offset", [1e6, 1e7])
def test_closest_approach_is_unchanged_far_from_the_origin(offset):
    # Expanded as |a|^2 + |b|^2 - 2 a.b, uncentred states at 1e7 cancelled every
    # distance of unit size to 0 (and the medium width to a sixteenth).
    rng = np.random.default_rng(7)
    trajs = [np.cumsum(rng.normal(scale=0.05, size=(30, 2)), axis=0) + rng.normal(size=2)
             for _ in range(6)]
    near = closest_approach_matrix(trajs)
    far = closest_approach_matrix([x + offset for x in trajs])
    np.testing.assert_allclose(far, near, rtol=1e-5)
    assert sigma2_heuristics([x + offset for x in trajs])["medium"] == pytest.approx(
        sigma2_heuristics(trajs)["medium"], rel=1e-5)
