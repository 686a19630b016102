"""Support states and spacing of the demonstrated data (extrapolation guard)."""

import numpy as np

from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.support import support_spacing, support_states


def _lines(rng, k=6, n=2, m=50):
    starts = rng.normal(size=(k, n))
    s = np.linspace(0.0, 1.0, m)[:, None]
    return [x0 * np.exp(-2.0 * s) for x0 in starts]


def test_spacing_is_leave_one_demonstration_out():
    # Two parallel lines 0.5 apart: every state's nearest other-demo state is 0.5 away,
    # however densely each line is sampled.
    t = np.linspace(0, 1, 200)[:, None]
    a = np.hstack([t, np.zeros_like(t)])
    b = np.hstack([t, np.full_like(t, 0.5)])
    S, g = support_states([a, b], max_points=400)
    assert np.isclose(support_spacing(S, g), 0.5)


def test_support_states_thin_and_label():
    rng = np.random.default_rng(0)
    trajs = _lines(rng, k=4, m=500)
    S, g = support_states(trajs, max_points=100)
    assert len(S) <= 100
    assert set(np.unique(g)) == {0, 1, 2, 3}


def test_model_support_query_roundtrip(tmp_path):
    rng = np.random.default_rng(1)
    trajs = _lines(rng)
    model = PolicyAlign().fit(trajs)
    d, nearest = model.support_query(trajs[0][:5])
    assert np.allclose(d, 0.0) and np.allclose(nearest, trajs[0][:5])
    far = trajs[0][:1] + 100.0
    d_far, _ = model.support_query(far)
    assert d_far[0] > 10.0
    loaded = PolicyAlign.load(model.save(tmp_path / "m.npz"))
    assert loaded.support_spacing_ == model.support_spacing_
    assert np.allclose(loaded.support_query(far)[0], d_far)
