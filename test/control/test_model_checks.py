"""What the executor checks about a model it loads (policy_align_ros.control.model_checks,
``install_model``): a model that learn refused and wrote only because it was forced is not
armed unless allowed. ROS-free; causes, flags, names and numbers are asserted, not words.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from policy_align_ros.control import (
    ArmedController,
    ControlStep,
    ZeroCause,
    apply_setting,
    arming_status,
    install_model,
    load_policy,
    model_refusals,
)
from policy_align_ros.control.model_checks import UNNAMED_REFUSAL
from policy_align_ros.control.status import WARN
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
