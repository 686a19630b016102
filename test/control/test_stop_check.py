"""The fold-stop check at arming (policy_align_ros.control.stop_check). ROS-free."""

import asyncio
import dataclasses
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from policy_align_ros.control import (
    ArmedController,
    ArmedRecheck,
    ArmingStopCheck,
    ControlStep,
    Output,
    TaskSpacePolicy,
    arming_status,
    check_in_slices,
    stop_check,
    stop_check_answer,
    stop_check_note,
)
from policy_align_ros.control.stop_check import MAX_SLOWDOWN
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.fold_stops import STOP_SPREAD_LIMIT

sys.path.insert(0, str(Path(__file__).parents[1] / "learning"))
from flows import quadratic_flow  # noqa: E402

A = np.array([[2.0, 0.3], [0.3, 1.0]])
CENTRE = np.array([0.2, -0.1])
ROW = np.array([1.0, 2.0])  # a constraint no demonstration showed: ROW . qdot = 0


class _Row:
    def matrix(self, q, qdot=None):
        return ROW[None, :]


class _Shifted:
    """A fold model whose potential is the model's moved by ``shift``."""

    def __init__(self, regressor, shift):
        self.regressor, self.shift = regressor, np.asarray(shift, dtype=float)

    def gradient(self, X):
        return self.regressor.gradient(X - self.shift)


def _fit(order=(0, 1)):
    """A 2-D model fitted on exact flows of the bowl, its coordinates in ``order``."""
    rng = np.random.default_rng(0)
    trajs = [quadratic_flow(A, CENTRE, rng.uniform(-1, 1, 2), 60, 0.05) for _ in range(8)]
    for t in trajs:
        t.positions = t.positions[:, list(order)]
    names = [["j0", "j1"][i] for i in order]
    return PolicyAlign(random_state=0).fit(trajs, joint_names=names)


@pytest.fixture(scope="module")
def model():
    return _fit()


def _step(policy, permutation=None):
    return ControlStep(-3 * np.ones(2), 3 * np.ones(2), np.full(2, 2.0), 0.01,
                       constraints=[_Row()], policy=policy, permutation=permutation)


def _constrained_minimum(q0):
    """The bowl's lowest point on the line through ``q0`` along which ROW . qdot = 0."""
    d = np.array([ROW[1], -ROW[0]])
    t = -(d @ A @ (q0 - CENTRE)) / (d @ A @ d)
    return q0 + t * d


def test_folds_of_exact_data_agree_and_the_run_keeps_to_the_constraint(model):
    step = _step(model.policy)
    check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    assert len(check.policies) == 1 + len(model.fold_regressors_)
    q0 = np.array([0.9, -0.8])
    found = check.prepare(step, q0).result()
    assert found.spread < STOP_SPREAD_LIMIT / 5 and not found.uncertain
    assert ROW @ (found.stop - q0) == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(found.stop, _constrained_minimum(q0), atol=0.02)
    assert stop_check_note(found) == ""
    # The executor's own step is left as it was.
    assert step.policy == model.policy and step.dt == 0.01 and step.guard is None


def test_folds_that_stop_elsewhere_make_the_stop_uncertain_and_it_is_said(model):
    shifted = PolicyAlign.__new__(PolicyAlign)
    shifted.__dict__.update(model.__dict__)
    shifted.fold_regressors_ = [_Shifted(model.regressor_, [0.0, 0.0]),
                                _Shifted(model.regressor_, [0.3, 0.0])]
    q0 = np.array([0.9, -0.8])
    found = ArmingStopCheck.for_model(shifted, shifted.policy, np.arange(2)).prepare(
        _step(shifted.policy), q0).result()
    assert found.uncertain and found.spread > 5 * STOP_SPREAD_LIMIT
    np.testing.assert_allclose(found.fold_stops[0], found.stop, atol=1e-6)
    out = Output(None, "", 1.0)
    note = stop_check_answer(found, out)
    assert note and out.events and out.events[0][0] == "warning"
    # Armed on such a run, /diagnostics warns and gives the spread.
    control = ArmedController(_step(shifted.policy), 2.0, 0.05)
    control.stop_spread = found
    ok_level, _, values = arming_status(control, 0, model="m", model_state="joints",
                                        constraints="[]", rejected={})
    assert values["stop_uncertain"] == "true"
    assert float(values["stop_spread"]) == pytest.approx(found.spread, abs=1e-3)
    control.armed = True
    level, _, _ = arming_status(control, 0, model="m", model_state="joints",
                                constraints="[]", rejected={})
    assert level > ok_level


def test_the_check_compares_stops_in_the_models_joint_order():
    swapped = _fit(order=(1, 0))
    q0 = np.array([0.9, -0.8])  # controller order j0, j1
    found = ArmingStopCheck.for_model(swapped, swapped.policy, np.array([1, 0])).prepare(
        _step(swapped.policy, permutation=[1, 0]), q0).result()
    # Reported in model order (j1, j0).
    np.testing.assert_allclose(found.stop[::-1], _constrained_minimum(q0), atol=0.02)
    assert not found.uncertain


def test_nothing_to_check_without_fold_models_or_a_clock(model):
    bare = PolicyAlign.__new__(PolicyAlign)
    bare.__dict__.update(model.__dict__)
    bare.fold_regressors_ = []
    assert ArmingStopCheck.for_model(bare, bare.policy, np.arange(2)) is None
    untimed = PolicyAlign.__new__(PolicyAlign)
    untimed.__dict__.update(model.__dict__)
    untimed.timed_ = False
    assert ArmingStopCheck.for_model(untimed, untimed.policy, np.arange(2)) is None
    assert stop_check_note(None) == "" and stop_check_answer(None, Output(None, "", 1.0)) == ""


def test_a_check_advanced_in_slices_ends_where_one_run_to_the_end_does(model):
    check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    q0 = np.array([-0.7, 0.6])
    whole = check.prepare(_step(model.policy), q0).result()
    sliced = check.prepare(_step(model.policy), q0)
    assert not sliced.advance(0.0) and sliced.stepped == 1  # a zero budget: one step
    while not sliced.advance(0.0):
        pass
    # Every run has stopped (its command at most 1 % of the demonstrations' speed) before
    # the most steps.
    assert sliced.finished and 1 < sliced.done < check.steps
    found = sliced.result()
    np.testing.assert_array_equal(found.stop, whole.stop)
    np.testing.assert_array_equal(found.fold_stops, whole.fold_stops)


def _sweeps(run):
    """The runs of ``run`` (a fresh StopCheckRun) as whole sweeps over them: the sweeps
    taken and each run's state at its end (the loop the sliced runs must equal)."""
    x, s = [run.q0.copy() for _ in run.fields], [run.state(run.q0)] * len(run.fields)
    moving, sweeps = [True] * len(run.fields), 0
    while sweeps < run.steps and any(moving):
        sweeps += 1
        for i, field in enumerate(run.fields):
            if moving[i]:
                y = x[i] + run.dt * field(x[i][None])[0]
                moving[i] = bool(np.linalg.norm(run.state(y) - s[i]) > run.settled * run.dt)
                if moving[i]:
                    x[i], s[i] = y, run.state(y)
    return sweeps, s


@pytest.mark.parametrize("cap", [None, 7])
def test_runs_advanced_a_step_at_a_time_equal_whole_sweeps(model, cap):
    check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    if cap is not None:
        check = dataclasses.replace(check, steps=cap)  # cut off while the runs move
    q0 = np.array([0.9, -0.8])
    sweeps, ends = _sweeps(check.prepare(_step(model.policy), q0))
    run = check.prepare(_step(model.policy), q0)
    while not run.advance(0.0):
        pass
    found = run.result()
    assert run.done == sweeps and (cap is None or sweeps == cap)
    np.testing.assert_array_equal(found.stop, ends[0])
    np.testing.assert_array_equal(found.fold_stops, np.array(ends[1:]))


class _HoldFirst:
    """Holds the first joint where it was latched: ``A = [1, 0]``."""

    def matrix(self, q, qdot=None):
        return np.array([[1.0, 0.0]])

    def hold_position(self, q):
        return np.asarray(q, dtype=float)[:1]


class _Sentinel:
    def scale(self, *args):
        return 1.0, 0.0


def test_preparing_a_check_leaves_the_live_steps_guard_and_held_frames_alone(model):
    step = ControlStep(-3 * np.ones(2), 3 * np.ones(2), np.full(2, 2.0), 0.01,
                       constraints=[_HoldFirst()], policy=model.policy, guard=_Sentinel())
    q_live = np.array([0.4, 0.2])
    step.latch(q_live)
    check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    found = check.prepare(step, np.array([-0.5, 0.9])).result()
    assert isinstance(step.guard, _Sentinel) and step.dt == 0.01
    np.testing.assert_array_equal(step.hold_errors(q_live), np.zeros(1))
    # The checked runs hold their own start's first joint.
    assert found.stop[0] == pytest.approx(-0.5, abs=1e-6)


def test_a_run_the_step_cannot_command_fails_the_check_rather_than_stop_there(model):
    check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    broken = dataclasses.replace(check, policies=[check.policies[0],
                                                  lambda X: np.full_like(X, np.nan)])
    with pytest.raises(RuntimeError):
        broken.prepare(_step(model.policy), np.array([0.9, -0.8])).result()


def test_runs_slowed_by_the_speed_limit_are_lengthened_at_most_fourfold(model):
    check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    fast = _step(model.policy)
    slow = ControlStep(-3 * np.ones(2), 3 * np.ones(2), np.full(2, check.speed / 2), 0.01,
                       constraints=[_Row()], policy=model.policy)
    crawl = ControlStep(-3 * np.ones(2), 3 * np.ones(2), np.full(2, check.speed / 100), 0.01,
                        constraints=[_Row()], policy=model.policy)
    q0 = np.array([0.9, -0.8])
    assert check.prepare(fast, q0).steps == check.steps  # the limit above the demos' speed
    assert check.prepare(slow, q0).steps == 2 * check.steps
    assert check.prepare(crawl, q0).steps == MAX_SLOWDOWN * check.steps


def test_a_check_in_slices_yields_between_slices_and_stops_when_superseded(model):
    check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    q0 = np.array([0.9, -0.8])
    pauses = []

    async def pause():
        pauses.append(1)

    run = check.prepare(_step(model.policy), q0)
    found = asyncio.run(check_in_slices(run, threading.Lock(), 0.0, pause, lambda: True))
    assert len(pauses) == run.stepped - 1  # one step per slice at a zero budget
    np.testing.assert_array_equal(found.stop, check.prepare(_step(model.policy), q0)
                                  .result().stop)
    wanted = iter([True, True, False])
    run = check.prepare(_step(model.policy), q0)
    assert asyncio.run(check_in_slices(run, threading.Lock(), 0.0, pause,
                                       lambda: next(wanted))) is None
    assert run.stepped == 2


def _armed(model, q, constraints):
    """An armed controller on ``model`` at ``q`` under ``constraints``, with its check."""
    step = ControlStep(-3 * np.ones(2), 3 * np.ones(2), np.full(2, 2.0), 0.01,
                       constraints=constraints, policy=model.policy)
    step.stop_check = ArmingStopCheck.for_model(model, model.policy, np.arange(2))
    control = ArmedController(step, 2.0, 0.05)
    control.joint_state(q, 1, 1)
    assert control.arm(1)[0]
    return control


def test_constraints_set_while_armed_are_checked_from_where_the_robot_stands(model,
                                                                            monkeypatch):
    monkeypatch.setattr(stop_check, "RECHECK_SHARE", 0.0)  # one step per slice
    q = np.array([0.9, -0.8])
    control = _armed(model, q, [])
    control.step.constraints = [_Row()]  # set while armed
    recheck = ArmedRecheck.begin(control, True)
    _, _, values = arming_status(control, 0, model="m", model_state="joints",
                                 constraints="[row]", rejected={}, checking=True)
    assert values["stop_spread"] == values["stop_uncertain"] == "checking"
    ended, found = recheck.advance(control, True)
    slices = 1
    while not ended:
        ended, found = recheck.advance(control, True)
        slices += 1
    assert slices == recheck.run.stepped > 1  # a slice after each control step
    np.testing.assert_allclose(found.stop, _constrained_minimum(q), atol=0.02)
    assert not found.uncertain
    # Nothing to check: the check off, disarmed, or no check for the model.
    assert ArmedRecheck.begin(control, False) is None
    control.step.stop_check = None
    assert ArmedRecheck.begin(control, True) is None
    assert ArmedRecheck.begin(_disarmed(model, q), True) is None


def _disarmed(model, q):
    control = _armed(model, q, [])
    control.disarm("test")
    return control


def test_a_recheck_takes_a_share_of_the_time_between_control_steps(model, monkeypatch):
    control = _armed(model, np.array([0.9, -0.8]), [_Row()])
    now = [0.0]
    recheck = ArmedRecheck.begin(control, True, clock=lambda: now[0])
    budgets = []
    monkeypatch.setattr(recheck.run, "advance", lambda b: budgets.append(b) or False)
    dt = control.step.dt
    for gap in (dt, dt / 10, 10 * dt):  # steps at the rate, faster (lockstep), late
        now[0] += gap
        recheck.advance(control, True)
    np.testing.assert_allclose(budgets, [stop_check.RECHECK_SHARE * g
                                         for g in (dt, dt / 10, dt)])
    control.step.dt = 1.0  # a slow rate: no slice longer than SLICE_S
    now[0] += 1.0
    recheck.advance(control, True)
    assert budgets[-1] == stop_check.SLICE_S


@pytest.mark.parametrize("change", ["constraints", "model", "disarm", "off"])
def test_a_recheck_made_moot_ends_without_a_result(model, change):
    control = _armed(model, np.array([0.9, -0.8]), [_Row()])
    recheck = ArmedRecheck.begin(control, True)
    on = True
    if change == "constraints":
        control.step.constraints = [_Row()]  # a set replaces the list
    elif change == "model":
        control.step.stop_check = dataclasses.replace(control.step.stop_check)
    elif change == "disarm":
        control.disarm("test")
    else:
        on = False
    assert recheck.advance(control, on) == (True, None)
    assert recheck.run.stepped == 0  # not a step of a moot check


class _HandBowl:
    """A timed task-space model of one frame: the bowl ``0.5 |x - centre|^2`` (m), and
    fold models with bowls at ``fold_centres``."""

    timed_ = True
    n_features_in_ = 3
    support_spacing_ = 0.005

    def __init__(self, centre, fold_centres):
        self.regressor_ = _Bowl(centre)
        self.fold_regressors_ = [_Bowl(c) for c in fold_centres]
        self.fit_summary_ = {"goal": {"extent": 0.3, "typical_speed": 0.1}}

    def policy(self, X):
        return -self.regressor_.gradient(X)


class _Bowl:
    def __init__(self, centre):
        self.centre = np.asarray(centre, dtype=float)

    def gradient(self, X):
        return X - self.centre


def test_a_task_space_model_is_checked_in_its_frames_positions(robot, hand_map):
    q0 = robot.neutral()
    hand = hand_map.kinematics(q0)[0]
    goal = hand + np.array([0.05, 0.0, 0.0])
    model = _HandBowl(goal, [goal, goal + np.array([0.0, 0.03, 0.0])])
    policy = TaskSpacePolicy(model, hand_map)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), 0.01,
                       policy=policy)
    check = ArmingStopCheck.for_model(model, policy, np.arange(robot.nq))
    assert check.speed is None  # no joint-speed comparison for frame states
    run = check.prepare(step, q0)
    found = run.result()
    assert run.done < run.steps  # every run stopped, in frame positions
    np.testing.assert_allclose(found.stop, goal, atol=0.003)
    np.testing.assert_allclose(found.fold_stops[1], goal + [0.0, 0.03, 0.0], atol=0.003)
    assert found.spread == pytest.approx(0.03 / np.linalg.norm(goal - hand), rel=0.1)
    assert found.uncertain
    # The executor's own policy and step are left as they were.
    assert policy.constraint is None and step.policy is policy
