"""The learnt goal in the learn summary (policy_align_ros.data.goal_digest). ROS-free."""

from __future__ import annotations

import json
import math
import re

from policy_align_ros.data.goal_digest import goal_digest, goal_text


def _goal(**changes):
    """A goal report as learning.goal.goal_summary and the fold spread write it."""
    goal = {"extent": 2.0, "typical_speed": 1.0, "n_rests": 4, "n_not_at_rest": 0,
            "n_constrained_rests": 1, "n_escaped": 0, "goal_error": 0.02,
            "goal_error_fraction": 0.01, "fold_spread_max": 0.004,
            "fold_spread_fraction": 0.002, "n_starts_elsewhere": 0,
            "demonstrated_goals": [{"point": [0.0, 0.0], "n_rests": 3}],
            "minima": [{"point": [0.01, 0.0]}, {"point": [1.0, 1.0]}]}
    return {**goal, **changes}


def test_the_digest_keeps_counts_and_distances_without_points_and_is_json():
    digest = goal_digest(_goal(fold_spread_max=math.inf, fold_spread_fraction=math.nan))
    assert digest["n_minima"] == 2 and digest["n_demonstrated_goals"] == 1
    assert digest["goal_error"] == 0.02 and digest["extent"] == 2.0
    assert digest["fold_spread_max"] is None and digest["fold_spread_fraction"] is None
    assert "minima" not in digest and "demonstrated_goals" not in digest
    assert json.loads(json.dumps(digest, allow_nan=False)) == digest
    assert goal_digest(None) is None and goal_digest({}) is None
    assert goal_digest(_goal(n_starts_elsewhere=2))["n_starts_elsewhere"] == 2
    assert goal_digest(_goal(n_starts_late=3))["n_starts_late"] == 3
    assert goal_digest(_goal())["n_starts_late"] is None  # reports written before the count


def test_late_starts_are_said_only_beyond_the_stranded_ones():
    base = goal_text(goal_digest(_goal(n_starts_elsewhere=1)))
    assert goal_text(goal_digest(_goal(n_starts_elsewhere=1, n_starts_late=1))) == base
    assert goal_text(goal_digest(_goal(n_starts_elsewhere=1, n_starts_late=2))) != base


def test_held_out_starts_are_said_only_where_the_fits_own_starts_reach():
    reaching = goal_text(goal_digest(_goal(n_starts_elsewhere=0, n_starts_late=0)))
    assert goal_digest(_goal(n_heldout_late=2))["n_heldout_late"] == 2
    assert goal_text(goal_digest(_goal(n_starts_late=0, n_heldout_late=2))) != reaching
    stranded = goal_text(goal_digest(_goal(n_starts_elsewhere=1)))
    assert goal_text(goal_digest(_goal(n_starts_elsewhere=1, n_heldout_late=2))) == stranded


def test_the_goal_in_words():
    assert goal_text(None) == ""
    text = goal_text(goal_digest(_goal(n_escaped=3)))
    # The minima, the goal error and the fold spread in % of the extent, the escapes.
    assert re.match(r"\D*\b2\b\D*\b1 %\D*\b0\.2 %\D*\b3\b\D*$", text)
    assert goal_text(goal_digest(_goal())) != text  # without escapes: not said
    one = goal_text(goal_digest(_goal(minima=[{}], fold_spread_fraction=None)))
    assert re.match(r"\D*\b1\b\D*\b1 %\D*$", one)  # no fold spread: not said


def test_without_a_goal_error_the_words_say_why():
    moving = _goal(goal_error=None, goal_error_fraction=None, n_rests=0,
                   demonstrated_goals=[])
    held = _goal(goal_error=None, goal_error_fraction=None, demonstrated_goals=[])
    texts = [goal_text(goal_digest(g)) for g in (moving, held, _goal())]
    assert len(set(texts)) == 3  # each case its own words
    assert all("1 %" not in t for t in texts[:2])  # no goal error is claimed


def test_rests_in_several_places_are_said_with_their_spread():
    one = goal_text(goal_digest(_goal(n_rest_places=1, rest_spread_fraction=0.0)))
    assert one == goal_text(goal_digest(_goal()))  # one place, or an older report: nothing
    apart = goal_digest(_goal(n_rest_places=4, rest_spread_fraction=0.62))
    assert apart["n_rest_places"] == 4 and apart["rest_spread_fraction"] == 0.62
    assert "62 %" in goal_text(apart) and "62 %" not in one


def test_without_a_demonstrated_goal_the_words_say_how_far_the_fit_extrapolated():
    # The learnt goal's distance to the nearest sample is then the one measure; with a
    # demonstrated goal its error says more, and reports written before it say nothing.
    minima = [{"point": [1.0, 0.0], "data_fraction": 0.21}, {"data_fraction": 0.01}]
    held = _goal(goal_error=None, goal_error_fraction=None, demonstrated_goals=[],
                 minima=minima)
    assert goal_digest(held)["minimum_data_fraction"] == 0.21  # no end distances: lowest
    # The learnt goal is the minimum nearest where the demonstrations end, not the lowest.
    ended = [{**minima[0], "end_distance": 0.9},
             {"point": [0.1, 0.0], "data_fraction": 0.01, "end_distance": 0.05}]
    assert goal_digest({**held, "minima": ended})["minimum_data_fraction"] == 0.01
    text = goal_text(goal_digest(held))
    assert "21 %" in text
    assert "21 %" not in goal_text(goal_digest(_goal(minima=minima)))
    far = [{**minima[0], "data_fraction": 1.42}]  # beyond the data by more than its extent
    assert "142 %" in goal_text(goal_digest({**held, "minima": far}))
    older = _goal(goal_error=None, goal_error_fraction=None, demonstrated_goals=[])
    assert goal_digest(older)["minimum_data_fraction"] is None
    assert goal_text(goal_digest(older)).count(" %") == 1  # the fold spread's alone
    assert goal_digest(_goal(minima=[]))["minimum_data_fraction"] is None


def test_new_starts_that_stop_elsewhere_are_said_and_older_reports_say_nothing():
    plain = goal_text(goal_digest(_goal()))
    assert goal_digest(_goal())["n_new_starts_elsewhere"] is None
    assert goal_text(goal_digest(_goal(n_new_starts=64, n_new_starts_elsewhere=0))) == plain
    said = goal_digest(_goal(n_new_starts=64, n_new_starts_elsewhere=5))
    assert said["n_new_starts_elsewhere"] == 5 and goal_text(said) != plain
    late = goal_digest(_goal(n_new_starts=64, n_new_starts_elsewhere=0, n_new_starts_late=3))
    assert late["n_new_starts_late"] == 3 and goal_text(late) != plain
    assert goal_digest(_goal(n_new_starts=64))["n_new_starts_late"] is None  # older files
