"""The ``executor`` node on what a new user could not see: a model that learn refused and
wrote only because it was forced, the guard holding the robot at the data's edge, a
learnt goal beyond the guard's reach, and which joint a broken joint state broke (own
rclpy.Context, domain ids 210-213, 217 and 218), and whether the CV folds' models stop an
armed run where the model does.

Assertions are on causes, flags, names and numbers, never on wording or wall-clock speed.
The logic is tested without a graph in test/control/test_model_checks.py and
test/control/test_guard_hold.py.
"""

import dataclasses

import numpy as np
import pytest
from executor_rig import JOINTS, _attractor_policy, _fit_model
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from policy_align_ros.control import ExtrapolationGuard, SupportDistance, ZeroCause
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.nodes import executor as executor_module

REFUSALS = ["no better than a zero policy: held-out error 0.31 >= a zero policy's 0.29",
            "no minimum: every descent left the data's box"]


def _values(array):
    return {kv.key: kv.value for kv in array.status[0].values}


def _latest(r):
    return _values(r.diagnostics[-1])


def test_a_forced_model_is_loaded_with_a_warning_but_not_armed_unless_allowed(rig, tmp_path):
    good = str(_fit_model(tmp_path / "good.npz", JOINTS, np.zeros(len(JOINTS))))
    model = PolicyAlign.load(good)
    model.fit_summary_["pipeline"] = {"forced": True, "refusals": list(REFUSALS)}
    forced = str(model.save(tmp_path / "forced.npz"))
    r = rig(210)
    # As the learner announces it on /learner/model (the executor follows the learner).
    assert r.node.set_parameters([Parameter("model_path", value=forced)])[0].successful
    assert r.node.model_path == forced and r.node.controller.step.policy is not None
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    response = r.enable(True)
    assert not response.success and not r.node.controller.armed
    assert all(refusal in response.message for refusal in REFUSALS)
    assert "allow_forced_model" in response.message
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics, what="diagnostics")
    values = _latest(r)
    assert values["zero_cause"] == ZeroCause.FORCED_MODEL and values["model_forced"] == "true"
    assert r.diagnostics[-1].status[0].level == r.diagnostics[-1].status[0].WARN
    # Opted in: the next enable arms it.
    assert r.node.set_parameters([Parameter("allow_forced_model", value=True)])[0].successful
    response = r.enable(True)
    assert response.success, response.message
    assert r.node.controller.armed
    # A model that passed is armed without the switch.
    assert r.node.set_parameters([Parameter("allow_forced_model", value=False)])[0].successful
    assert r.node.set_parameters([Parameter("model_path", value=good)])[0].successful
    assert r.enable(True).success


def test_a_hold_at_the_datas_edge_is_reported_at_once_with_the_limit_that_binds(rig,
                                                                                 monkeypatch):
    # The periodic status out of reach: a status seen while armed is the hold's.
    monkeypatch.setattr(executor_module, "DIAGNOSTICS_PERIOD_S", 1e6)
    r = rig(211)
    control = r.node.controller
    q0 = r.q.copy()
    # Data at one posture 0.36 rad apart; the robot stands 0.52 rad from it and the policy
    # leads further out: the rad cap holds it (1.44 spacings, far inside 6).
    data = SimpleSupport(q0 - 0.52 * np.eye(len(JOINTS))[0], spacing=0.36)
    control.set_policy(_attractor_policy(q0 + np.eye(len(JOINTS))[0]))
    control.step.guard = ExtrapolationGuard(SupportDistance(data), 6.0,
                                            max_extrapolation_rad=0.5)
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.diagnostics) >= 2, what="the hold's status")
    values = _values(r.diagnostics[1])
    assert values["armed"] == "true" and values["zero_cause"] == ZeroCause.EXTRAPOLATION_HOLD
    assert values["extrapolation_hold"] == "max_extrapolation_rad"
    assert float(values["extrapolation_distance_rad"]) == pytest.approx(0.52, abs=1e-3)
    assert float(values["extrapolation_distance"]) == pytest.approx(0.52 / 0.36, abs=0.01)
    assert r.node._hold_log.holding and control.armed
    # Once: holding on sends no further status (nothing else changes).
    r.spin(0.3)
    assert len(r.diagnostics) == 2 and not np.any(r.commands[-1] if r.commands else 0.0)


class SimpleSupport:
    """The support part of a model: one support state ``centre``, ``spacing`` apart."""

    def __init__(self, centre, spacing):
        self.centre, self.support_spacing_ = np.asarray(centre, dtype=float), spacing
        self.n_features_in_ = len(self.centre)

    def support_query(self, X):
        d = np.linalg.norm(X - self.centre, axis=1) / self.support_spacing_
        return d, np.tile(self.centre, (len(X), 1))


def test_a_learnt_goal_beyond_the_guards_reach_is_reported_and_armed(rig, tmp_path):
    good = str(_fit_model(tmp_path / "good.npz", JOINTS, np.zeros(len(JOINTS))))
    model = PolicyAlign.load(good)
    goal = model.fit_summary_["goal"]
    edge = model.support_states_[np.argmax(model.support_states_[:, 0])]
    for minimum in goal["minima"]:  # whichever is the learnt goal, 0.59 rad out
        minimum["point"] = (edge + 0.59 * np.eye(len(edge))[0]).tolist()
    far = str(model.save(tmp_path / "far_goal.npz"))
    r = rig(212, model_path=far)
    r.spin_until(lambda: r.diagnostics, what="diagnostics")
    values = _latest(r)
    assert values["goal_beyond_guard"] == "true"
    assert float(values["goal_distance_rad"]) == pytest.approx(0.59, abs=1e-3)
    assert float(values["goal_reach_rad"]) == pytest.approx(0.5, abs=1e-3)
    assert "0.59" in values["model_warnings"]
    # Not refused: the user may mean it.
    r.enable_when_fresh()
    assert r.node.controller.armed
    # Raised at run time, the guard reaches it.
    assert r.node.set_parameters([Parameter("max_extrapolation_rad", value=2.0)])[0].successful
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics, what="diagnostics")
    assert _latest(r)["goal_beyond_guard"] == "false"


def test_a_broken_joint_state_names_the_joint_and_is_reported_as_rejected(rig):
    r = rig(213)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.diagnostics) >= 1 and _latest(r)["armed"] == "true",
                 what="armed diagnostics")
    position = r.q.copy()
    position[3] = np.nan
    msg = JointState(name=JOINTS, position=position.tolist())
    msg.header.stamp = r.node.get_clock().now().to_msg()
    r.states.publish(msg)
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False, what="disarm")
    r.spin_until(lambda: _latest(r)["armed"] == "false", publish_states=False,
                 what="the disarm's status")
    values = _latest(r)  # published at once, before any valid state arrived again
    assert values["zero_cause"] == ZeroCause.NON_FINITE_STATE
    assert JOINTS[3] in values["zero_reason"] and JOINTS[2] not in values["zero_reason"]
    assert JOINTS[3] in values["joint_states"] and values["joint_states"] != "fresh"
    # The next valid states make them fresh again; the cause stays until enabled.
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.node.controller.zero_cause == ZeroCause.NON_FINITE_STATE


def test_enable_runs_the_fold_stop_check_and_says_when_the_stop_is_uncertain(rig, tmp_path):
    centre = np.zeros(len(JOINTS))
    good = str(_fit_model(tmp_path / "good.npz", JOINTS, centre))
    r = rig(217, model_path=good)
    check = r.node.controller.step.stop_check
    assert check is not None and len(check.policies) > 1  # the model and its folds
    r.enable_when_fresh()
    # Exact data: the folds agree, and the status says so while armed.
    assert r.node.controller.stop_spread is not None
    assert not r.node.controller.stop_spread.uncertain
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics and _latest(r)["armed"] == "true",
                 what="armed diagnostics")
    assert _latest(r)["stop_uncertain"] == "false"
    assert r.diagnostics[-1].status[0].level == r.diagnostics[-1].status[0].OK
    assert r.enable(False).success
    # A fold model that stops the run 0.3 rad away per joint: uncertain, said, still armed.
    shifted = _attractor_policy(centre + 0.3)
    r.node.controller.step.stop_check = dataclasses.replace(
        check, policies=[check.policies[0], shifted])
    r.spin(0.1)
    answer = r.enable(True)
    assert answer.success
    assert r.node.controller.armed and r.node.controller.stop_spread.uncertain
    assert f"{100 * r.node.controller.stop_spread.spread:.0f} %" in answer.message
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics and _latest(r)["armed"] == "true",
                 what="armed diagnostics")
    assert _latest(r)["stop_uncertain"] == "true"
    assert r.diagnostics[-1].status[0].level == r.diagnostics[-1].status[0].WARN
    # New constraints while armed: the check of the old ones is dropped (and the new ones
    # checked: test_constraints_set_while_armed_are_checked_from_where_the_robot_stands).
    assert r.node.set_parameters([Parameter("constraints", value="[]")])[0].successful
    assert r.node.controller.stop_spread is None
    assert r.enable(False).success
    # A fold model the step cannot command: the check runs and fails, and arming goes on.
    called = []

    def broken(X):
        called.append(1)
        return np.full_like(X, np.nan)

    r.node.controller.step.stop_check = dataclasses.replace(
        check, policies=[check.policies[0], broken])
    r.spin(0.1)
    assert r.enable(True).success and r.node.controller.armed
    assert called and r.node.controller.stop_spread is None
    assert r.enable(False).success
    # Constraints set while the check runs (here by its first step): that enable is refused.
    step = r.node.controller.step

    def resets_constraints(X):
        step.constraints = list(step.constraints)  # as a parameter set replaces them
        return check.policies[0](X)

    step.stop_check = dataclasses.replace(check, policies=[resets_constraints,
                                                          *check.policies[1:]])
    r.spin(0.1)
    assert not r.enable(True).success and not r.node.controller.armed
    assert r.enable(False).success
    # Switched off, no check runs.
    assert r.node.set_parameters([Parameter("stop_check", value=False)])[0].successful
    r.spin(0.1)
    assert r.enable(True).success
    assert r.node.controller.stop_spread is None


@pytest.mark.parametrize("lockstep", [False, True])
def test_constraints_set_while_armed_are_checked_from_where_the_robot_stands(rig, tmp_path,
                                                                             lockstep):
    centre = np.zeros(len(JOINTS))
    r = rig(218, model_path=str(_fit_model(tmp_path / "good.npz", JOINTS, centre)),
            step_on_joint_state=lockstep)
    check = r.node.controller.step.stop_check
    r.enable_when_fresh()
    assert not r.node.controller.stop_spread.uncertain
    # A fold model that stops the run 0.3 rad away per joint, then new constraints: the
    # check of the old ones is dropped, the new ones are checked after the control steps.
    r.node.controller.step.stop_check = dataclasses.replace(
        check, policies=[check.policies[0], _attractor_policy(centre + 0.3)])
    assert r.node.set_parameters([Parameter("constraints", value="[]")])[0].successful
    assert r.node.controller.stop_spread is None and r.node._recheck is not None
    r.spin_until(lambda: r.node.controller.stop_spread is not None,
                 what="the check of the new constraints")
    assert r.node.controller.armed and r.node.controller.stop_spread.uncertain
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics and _latest(r)["stop_uncertain"] == "true",
                 what="uncertain diagnostics")
    assert r.diagnostics[-1].status[0].level == r.diagnostics[-1].status[0].WARN
    # A check still running (one that would run for ever here) is shown, and a disarm
    # drops it.
    r.node.controller.step.stop_check = dataclasses.replace(check, steps=10**9, settled=0.0)
    assert r.node.set_parameters([Parameter("constraints", value="[]")])[0].successful
    r.spin_until(lambda: r.node._recheck.run.stepped > 0, what="the check's first slice")
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics, what="diagnostics")
    assert _latest(r)["stop_spread"] == "checking" and r.node.controller.armed
    assert r.enable(False).success
    assert r.node._recheck is None and r.node.controller.stop_spread is None
    # A fold model the step cannot command: the check fails (logged), still armed.
    r.node.controller.step.stop_check = check
    r.enable_when_fresh()
    r.node.controller.step.stop_check = dataclasses.replace(
        check, policies=[check.policies[0], lambda X: np.full_like(X, np.nan)])
    assert r.node.set_parameters([Parameter("constraints", value="[]")])[0].successful
    assert r.node._recheck is not None
    r.spin_until(lambda: r.node._recheck is None, what="the failed check")
    assert r.node.controller.armed and r.node.controller.stop_spread is None
