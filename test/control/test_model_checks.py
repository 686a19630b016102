"""What the executor checks about a model it loads (policy_align_ros.control.model_checks,
``install_model``): a model that learn refused and wrote only because it was forced is not
armed unless allowed; a learnt goal beyond the extrapolation guard's reach is reported
with both distances. ROS-free; causes, flags, names and numbers are asserted, not words.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from policy_align_ros.control import (
    ArmedController,
    ControlStep,
    ExtrapolationGuard,
    GoalReach,
    ZeroCause,
    apply_setting,
    arming_status,
    goal_reach,
    install_model,
    learnt_goal,
    load_policy,
    model_refusals,
)
from policy_align_ros.control.model_checks import UNNAMED_REFUSAL
from policy_align_ros.control.status import OK, WARN
from policy_align_ros.data import write_joint_state_bag
from policy_align_ros.data.pipeline import learn_pipeline
from policy_align_ros.experiments.toy import make_toy_dataset
from policy_align_ros.kinematics import Robot
from policy_align_ros.learning import PolicyAlign

JOINTS = ["panda_joint1", "panda_joint2"]
REFUSALS = ["no better than a zero policy: held-out error 0.31 >= a zero policy's 0.29",
            "no minimum: every descent left the data's box"]
NOW = 1_000_000_000


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A model that passed (no pipeline block), and the same recorded as forced."""
    data = make_toy_dataset("sinusoid", 10, 25, np.random.default_rng(0))
    model = PolicyAlign(sigma="medium").fit(data.trajectories, joint_names=JOINTS)
    model.robot_ = "panda"
    root = tmp_path_factory.mktemp("checks")
    plain = str(model.save(root / "plain.npz"))
    model.fit_summary_ = {**model.fit_summary_,
                          "pipeline": {"forced": True, "refusals": list(REFUSALS)}}
    forced = str(model.save(root / "forced.npz"))
    return plain, forced


def _controller(robot):
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), 0.01,
                       max_acceleration=2.0, joint_limit_margin=0.05)
    return ArmedController(step, 2.0, 0.05, joint_names=list(robot.joint_names))


def _install(controller, robot, path, **guard):
    model, policy, perm, state = load_policy(path, robot)
    limits = {"max_extrapolation": 6.0, "max_extrapolation_rad": 0.5, **guard}
    return install_model(controller, robot, path, model, policy, perm, state, **limits)


def _status(controller, model="m.npz"):
    level, _, values = arming_status(controller, NOW, model=model, model_state="joints",
                                     constraints="[]", rejected={})
    return level, values


def test_the_learn_pipelines_forced_model_is_recognised_by_its_refusals(tmp_path):
    # Random walks: no better than a zero policy; learn refuses, --force writes it.
    rng = np.random.default_rng(5)
    for k in range(7):
        q = np.cumsum(rng.normal(scale=0.05, size=(60, 2)), axis=0) + rng.uniform(-1, 1, 2)
        stamps = 10**18 + k * 10**10 + np.arange(len(q)) * 50_000_000
        write_joint_state_bag(tmp_path / "walks" / f"demo_{k:04d}", JOINTS, stamps, q)
    with pytest.warns(UserWarning):
        result = learn_pipeline([tmp_path / "walks"], tmp_path / "m.npz", force=True)
    assert result.written and result.refusals
    model = PolicyAlign.load(tmp_path / "m.npz")
    assert model_refusals(model) == tuple(result.refusals)


def test_what_a_header_records_makes_a_model_forced_or_not():
    def model(pipeline):
        return SimpleNamespace(fit_summary_={"pipeline": pipeline})

    assert model_refusals(model({"forced": True, "refusals": REFUSALS})) == tuple(REFUSALS)
    assert model_refusals(model({"forced": False, "refusals": []})) == ()
    # Recorded as forced without naming why: still forced.
    assert model_refusals(model({"forced": True, "refusals": []})) == (UNNAMED_REFUSAL,)
    # A refused fit is only ever written when forced: refusals alone mean forced.
    assert model_refusals(model({"refusals": REFUSALS[:1]})) == tuple(REFUSALS[:1])
    # Saved without the learn pipeline, or by a version before it: not forced.
    assert model_refusals(SimpleNamespace(fit_summary_={})) == ()
    assert model_refusals(SimpleNamespace()) == ()


def test_a_forced_model_is_not_armed_unless_allowed_and_is_warned_about(fitted):
    plain, forced = fitted
    robot = Robot.load("panda", JOINTS)
    control = _controller(robot)
    out = _install(control, robot, forced)
    warnings = [text for level, text in out.events if level == "warning"]
    assert any(all(r in text for r in REFUSALS) for text in warnings), out.events
    control.joint_state(np.zeros(2), NOW, NOW)
    cause, reason = control.arm_check(NOW)
    assert cause == ZeroCause.FORCED_MODEL
    assert all(r in reason for r in REFUSALS) and "allow_forced_model" in reason
    accepted, _, _ = control.arm(NOW)
    assert not accepted and not control.armed
    level, values = _status(control)
    assert values["zero_cause"] == ZeroCause.FORCED_MODEL and level == WARN
    assert values["model_forced"] == "true" and values["allow_forced_model"] == "false"
    assert all(r in values["zero_reason"] for r in REFUSALS)
    # Allowed at run time: the next enable arms it, and the report says it is allowed.
    assert apply_setting(control, "allow_forced_model", True, robot.velocity_limit)
    assert control.arm(NOW)[0] and control.armed
    level, values = _status(control)
    assert values["zero_cause"] == "none" and values["model_forced"] == "true"
    assert values["allow_forced_model"] == "true"
    # Allowing it off again does not disarm; the next enable after a disarm is refused.
    apply_setting(control, "allow_forced_model", False, robot.velocity_limit)
    assert control.armed
    control.disarm("disabled by ~/enable")
    assert control.arm_check(NOW)[0] == ZeroCause.FORCED_MODEL
    # A model that passed replaces the refusals: armed without the switch.
    out = _install(control, robot, plain)
    assert control.step.model_refusals == ()
    assert not any(r in text for _, text in out.events for r in REFUSALS)
    assert control.arm(NOW)[0]
    assert _status(control)[1]["model_forced"] == "false"


def _goal_away_from_the_data(model, rad):
    """``model`` with its learnt goal moved ``rad`` beyond the support state farthest along
    the first joint, in that direction: then ``rad`` from the nearest one."""
    goal = model.fit_summary_["goal"]
    index = next(i for i, m in enumerate(goal["minima"])
                 if np.allclose(m["point"], learnt_goal(model)))
    edge = model.support_states_[np.argmax(model.support_states_[:, 0])]
    goal["minima"][index]["point"] = (edge + rad * np.eye(len(edge))[0]).tolist()
    return model


def test_a_learnt_goal_beyond_the_guards_reach_is_reported_and_not_refused(fitted, tmp_path):
    plain, _ = fitted
    # Two short demonstrations left a learnt goal 0.59 rad from the nearest sample.
    model = _goal_away_from_the_data(PolicyAlign.load(plain), 0.59)
    path = str(model.save(tmp_path / "far_goal.npz"))
    robot = Robot.load("panda", JOINTS)
    control = _controller(robot)
    out = _install(control, robot, path)
    reach = control.step.goal_reach
    assert reach.distance_rad == pytest.approx(0.59, abs=1e-9)
    step = control.step
    limits = (step.guard, step.max_velocity, step.max_acceleration)
    reach_rad, limit = reach.reach_rad(*limits)
    assert limit == "max_extrapolation_rad" and reach_rad == pytest.approx(0.5)
    assert reach.beyond(*limits)
    warnings = [text for level, text in out.events if level == "warning"]
    assert any("0.59" in text and "0.50" in text and "max_extrapolation_rad" in text
               for text in warnings), out.events
    # Not refused: the user may mean it.
    control.joint_state(np.zeros(2), NOW, NOW)
    assert control.arm(NOW)[0]
    level, values = _status(control)
    assert level == OK and values["zero_cause"] == "none"
    assert values["goal_beyond_guard"] == "true"
    assert float(values["goal_distance_rad"]) == pytest.approx(0.59, abs=1e-3)
    assert float(values["goal_reach_rad"]) == pytest.approx(0.5, abs=1e-3)
    assert "0.59" in values["model_warnings"]
    # The cap raised at run time to what the warning suggests: the goal is within reach.
    suggested = reach.fixes(*limits)["max_extrapolation_rad"]
    assert list(reach.fixes(*limits)) == ["max_extrapolation_rad"] and suggested > 0.59
    assert f"{suggested:.2f}" in reach.problem(*limits)
    apply_setting(control, "max_extrapolation_rad", suggested, robot.velocity_limit)
    assert not reach.beyond(*limits) and reach.problem(*limits) == ""
    values = _status(control)[1]
    assert values["goal_beyond_guard"] == "false" and values["model_warnings"] == "none"
    # A goal 0.2 rad from the data, within the default reach: no report.
    near = _goal_away_from_the_data(PolicyAlign.load(plain), 0.2)
    _install(control, robot, str(near.save(tmp_path / "near_goal.npz")))
    step = control.step
    assert step.goal_reach.distance_rad == pytest.approx(0.2, abs=1e-9)
    assert not step.goal_reach.beyond(step.guard, step.max_velocity, step.max_acceleration)
    assert _status(control)[1]["goal_beyond_guard"] == "false"


def test_the_limit_in_spacings_is_named_when_it_binds():
    # Data 0.01 rad apart: max_extrapolation (6 spacings plus the stopping band) ends the
    # reach at 0.21 rad, well inside max_extrapolation_rad 0.5.
    vmax, acc, spacing = np.full(6, 0.5), 2.0, 0.01
    guard = ExtrapolationGuard(lambda q: (0.0, None), 6.0, max_extrapolation_rad=0.5)
    reach = GoalReach(distance=0.3 / spacing, grad_norm=1.0 / spacing)
    assert reach.distance_rad == pytest.approx(0.3)
    reach_rad, limit = reach.reach_rad(guard, vmax, acc)
    assert limit == "max_extrapolation" and reach_rad < 0.3 and reach.beyond(guard, vmax, acc)
    assert reach.fixes(guard, vmax, acc) == {"max_extrapolation": 30.0}
    problem = reach.problem(guard, vmax, acc)
    assert "30.00" in problem and "max_extrapolation_rad" not in problem
    # A goal on a support state has no direction and is always within reach.
    on_data = GoalReach(distance=0.0, grad_norm=float("nan"))
    assert on_data.distance_rad == 0.0 and not on_data.beyond(guard, vmax, acc)


def test_no_goal_reach_without_a_guard_or_for_a_frames_model(fitted):
    plain, _ = fitted
    model = PolicyAlign.load(plain)
    perm = np.arange(2)
    guard = ExtrapolationGuard(lambda q: (1.0, np.ones(2)))
    assert goal_reach(model, perm, None) is None
    model.state_definition_ = {"type": "frames"}
    assert goal_reach(model, perm, guard) is None
