"""``tools/direction_grid.py``: the rule ``direction_weight="auto"`` applies, replayed over
fits at every weight (``docs/design/goal_anchor.md``)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))

import direction_grid  # noqa: E402

from policy_align_ros.learning.regressors.trend_kernel.model import (  # noqa: E402
    DIRECTION_WEIGHTS,
)


def _rows(elsewhere: dict[float, int], saddles: tuple[float, ...] = ()) -> list[dict]:
    return [{"shape": "S", "demo": 0, "weight": w, "elsewhere": e, "minimum": w not in saddles,
             "nV": 1.0 / w, "converged": e == 0} for w, e in elsewhere.items()]


def test_the_rule_keeps_the_largest_weight_of_the_grid_whose_starts_reach_the_goal():
    rows = _rows({10.0: 0, 100.0: 0, 1000.0: 2, 3000.0: 1})
    assert direction_grid._rule(rows, DIRECTION_WEIGHTS)["weight"] == 100.0
    assert direction_grid._rule(rows, (10.0, 1000.0))["weight"] == 10.0


def test_when_every_weight_strands_a_start_the_rule_keeps_the_smallest():
    rows = _rows({10.0: 1, 100.0: 3, 1000.0: 2, 3000.0: 1})
    assert direction_grid._rule(rows, DIRECTION_WEIGHTS)["weight"] == 10.0


def test_a_weight_whose_goal_is_a_saddle_is_passed_over():
    rows = _rows({10.0: 0, 100.0: 0, 1000.0: 0, 3000.0: 0}, saddles=(1000.0, 3000.0))
    assert direction_grid._rule(rows, DIRECTION_WEIGHTS)["weight"] == 100.0
