"""The ``executor`` node on what a new user could not see: a model that learn refused and
wrote only because it was forced (own rclpy.Context, domain id 210).

Assertions are on causes, flags, names and numbers, never on wording or wall-clock speed.
The logic is tested without a graph in test/control/test_model_checks.py.
"""

import numpy as np
from executor_rig import JOINTS, _fit_model
from rclpy.parameter import Parameter

from policy_align_ros.control import ZeroCause
from policy_align_ros.learning import PolicyAlign

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
