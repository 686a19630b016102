"""Integration tests of the ``learner`` node (own rclpy.Context, domain ids 160-169,
199, 217, 231)."""

import re
import threading
import time
import warnings

import numpy as np
import pytest
import rclpy
from log_rig import logged
from rcl_interfaces.srv import GetParameters
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger

from policy_align_ros.data import write_joint_state_bag
from policy_align_ros.data.pipeline import HOLDOUT_RANGE, observed_ncpe, parse_sigma
from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.nodes import learner as learner_module
from policy_align_ros.nodes._common import LATCHED_QOS
from policy_align_ros.nodes.learner import Learner

JOINTS = ["j1", "j2"]


def _write_dataset(directory, n_demos=10, seed=0, joints=JOINTS):
    """2-D demonstrations of pi = -x under a random line constraint each (dt 0.05 s)."""
    rng = np.random.default_rng(seed)
    for k in range(n_demos):
        alpha = rng.normal(size=2)
        N = np.eye(2) - np.outer(alpha, alpha) / (alpha @ alpha)
        x = rng.uniform(-2.0, 2.0, 2)
        X = []
        for _ in range(40):
            X.append(x.copy())
            x = x + 0.05 * (N @ -x)
        stamps = 10**18 + k * 10**10 + np.arange(40) * 50_000_000
        write_joint_state_bag(directory / f"demo_{k:04d}", joints, stamps, np.array(X))


class Rig:
    node_class = Learner

    def __init__(self, domain_id, **params):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = self.node_class(context=self.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.probe = Node("probe", context=self.context)
        self.models: list[str] = []
        self.probe.create_subscription(
            String, "/learner/model", lambda m: self.models.append(m.data), LATCHED_QOS)
        self.client = self.probe.create_client(Trigger, "/learner/learn")
        self.executor = MultiThreadedExecutor(num_threads=3, context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def learn(self, timeout=60.0):
        assert self.client.wait_for_service(timeout_sec=5.0)
        future = self.client.call_async(Trigger.Request())
        end = time.monotonic() + timeout
        while not future.done() and time.monotonic() < end:
            time.sleep(0.01)
        return future.result()

    def close(self):
        self.executor.shutdown()
        self.thread.join(timeout=5.0)
        self.probe.destroy_node()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def rig():
    made = []

    def make(domain_id, **params):
        made.append(Rig(domain_id, **params))
        return made[-1]

    yield make
    for r in made:
        r.close()


def test_learn_writes_the_model_publishes_it_and_summarises(rig, tmp_path):
    _write_dataset(tmp_path / "demos")
    model = tmp_path / "out" / "model.npz"
    r = rig(160, dataset_dir=str(tmp_path / "demos"), model_path=str(model))
    response = r.learn()
    assert response.success, response.message
    assert model.is_file()
    text = response.message
    # The answer is made from the summary stored in the model header.
    block = PolicyAlign.load(model).fit_summary_["pipeline"]
    assert r.node.last_result.summary == block and text == r.node.last_result.line()
    assert len(block["demonstrations"]["training"]) == 8
    assert len(block["demonstrations"]["held_out"]) == 2 and block["sigma2"] > 0
    assert block["heldout_ncpe_observed"] is not None
    # The numbers a user reads in it: sigma^2, the held-out nCPE, the model file.
    assert f"{block['sigma2']:.4g}" in text
    assert f"{block['heldout_ncpe_observed']:.4f}" in text and str(model) in text
    end = time.monotonic() + 5.0
    while not r.models and time.monotonic() < end:
        time.sleep(0.01)
    assert r.models == [str(model.resolve())]


def test_a_refused_fit_answers_false_keeps_the_model_and_publishes_nothing(rig, tmp_path):
    _write_dataset(tmp_path / "demos")
    model = tmp_path / "model.npz"
    r = rig(165, dataset_dir=str(tmp_path / "demos"), model_path=str(model))
    assert r.learn().success
    end = time.monotonic() + 5.0
    while not r.models and time.monotonic() < end:
        time.sleep(0.01)
    assert r.models == [str(model.resolve())]
    before = model.read_bytes()
    published = []
    real_publish = r.node._pub.publish
    r.node._pub.publish = lambda msg: (published.append(msg.data), real_publish(msg))
    # A kernel far narrower than the gaps between demonstrations: most cannot be aligned.
    assert r.node.set_parameters([Parameter("sigma", value="1e-6")])[0].successful
    response = r.learn()
    result = r.node.last_result
    assert not response.success and result.refused and not result.written
    # The gate that refused it: more demonstrations left unaligned than allowed.
    demos, gates = result.summary["demonstrations"], result.summary["gates"]
    assert len(demos["unaligned"]) > gates["max_discarded_fraction"] * len(demos["training"])
    assert str(model) in response.message  # the file kept as it was
    assert model.read_bytes() == before and published == []
    time.sleep(0.3)  # a stray announcement would have arrived by now
    assert r.models == [str(model.resolve())]
    # force writes it and announces it.
    assert r.node.set_parameters([Parameter("force", value=True)])[0].successful
    response = r.learn()
    result = r.node.last_result
    assert response.success and result.written and result.refusals  # refused, yet written
    assert published == [str(model.resolve())]
    assert PolicyAlign.load(model).fit_summary_["pipeline"]["forced"]


@pytest.mark.filterwarnings("ignore:PolicyAlign:UserWarning")  # the fit's own warning
def test_a_model_no_better_than_a_zero_policy_is_refused_with_the_goal_report(rig, tmp_path):
    rng = np.random.default_rng(3)
    for k in range(7):  # random walks: nothing to learn
        X = np.cumsum(rng.normal(scale=0.05, size=(60, 2)), axis=0)
        stamps = 10**18 + k * 10**10 + np.arange(60) * 50_000_000
        write_joint_state_bag(tmp_path / "walks" / f"demo_{k:04d}", JOINTS, stamps, X)
    model = tmp_path / "model.npz"
    r = rig(168, dataset_dir=str(tmp_path / "walks"), model_path=str(model))
    response = r.learn()
    assert not response.success and not model.exists() and r.node.last_result.refused
    summary = r.node.last_result.summary
    assert summary["worse_than_zero"] and summary["goal"]["extent"] > 0


def test_state_and_gate_parameters_are_validated_and_a_bad_frame_is_named(rig, tmp_path):
    arm = ["arm_left_1_joint", "arm_left_2_joint"]
    _write_dataset(tmp_path / "demos", n_demos=4, joints=arm)
    r = rig(166, dataset_dir=str(tmp_path / "demos"), model_path=str(tmp_path / "m.npz"),
            state="frames:no_such_frame", joints=["arm_left_1_joint", "arm_left_9_joint"],
            robot="talos")
    assert not r.node.set_parameters([Parameter("state", value="hands")])[0].successful
    assert not r.node.set_parameters(
        [Parameter("max_discarded_fraction", value=1.5)])[0].successful
    # The frame is checked before any bag is read.
    response = r.learn()
    assert not response.success and "no_such_frame" in response.message
    assert r.node.set_parameters(
        [Parameter("state", value="frames:arm_left_7_link")])[0].successful
    response = r.learn()
    assert not response.success and r.node.last_result is None
    # The joint not found, and the ones there are.
    assert "'arm_left_9_joint'" in response.message
    assert all(joint in response.message for joint in arm)
    assert not (tmp_path / "m.npz").exists() and r.models == []


def test_learn_fails_cleanly_without_data(rig, tmp_path):
    (tmp_path / "empty").mkdir()
    r = rig(161, dataset_dir=str(tmp_path / "empty"), model_path=str(tmp_path / "m.npz"))
    response = r.learn()
    assert not response.success and response.message and r.node.last_result is None
    r.node.set_parameters([Parameter("dataset_dir", value=str(tmp_path / "missing"))])
    response = r.learn()
    assert not response.success and str(tmp_path / "missing") in response.message
    assert not (tmp_path / "m.npz").exists() and r.models == []


def test_learn_fails_cleanly_with_a_single_demonstration(rig, tmp_path):
    _write_dataset(tmp_path / "one", n_demos=1)
    r = rig(162, dataset_dir=str(tmp_path / "one"), model_path=str(tmp_path / "m.npz"))
    response = r.learn()
    assert not response.success and r.node.last_result is None
    assert "gap_s" in response.message  # the fix for one continuous recording


def test_holdout_range_and_a_model_of_other_joints_needs_overwrite(rig, tmp_path):
    _write_dataset(tmp_path / "demos", n_demos=6)
    _write_dataset(tmp_path / "other", n_demos=6, joints=["a1", "a2"])
    model = tmp_path / "model.npz"
    r = rig(169, dataset_dir=str(tmp_path / "demos"), model_path=str(model))
    low, high = HOLDOUT_RANGE
    for value, ok in ((high, True), (high + 0.01, False), (low - 0.01, False)):
        result = r.node.set_parameters([Parameter("holdout_fraction", value=value)])[0]
        assert result.successful == ok, value
    assert r.learn().success
    before = model.read_bytes()
    r.node.set_parameters([Parameter("dataset_dir", value=str(tmp_path / "other")),
                           Parameter("force", value=True)])
    response = r.learn()
    assert not response.success and "overwrite" in response.message
    assert model.read_bytes() == before
    assert r.node.set_parameters([Parameter("overwrite", value=True)])[0].successful
    response = r.learn()
    assert response.success, response.message
    assert PolicyAlign.load(model).joint_names_ == ["a1", "a2"]


def test_node_stays_responsive_and_refuses_a_second_run_while_learning(
        rig, tmp_path, monkeypatch):
    import policy_align_ros.nodes.learner as learner_module

    real = learner_module.learn_pipeline
    started = threading.Event()

    def slow_learn(*args, **kwargs):
        started.set()
        time.sleep(1.5)  # a long fit
        return real(*args, **kwargs)

    monkeypatch.setattr(learner_module, "learn_pipeline", slow_learn)
    _write_dataset(tmp_path / "demos")
    r = rig(163, dataset_dir=str(tmp_path / "demos"), model_path=str(tmp_path / "m.npz"))
    assert r.client.wait_for_service(timeout_sec=5.0)
    first = r.client.call_async(Trigger.Request())
    assert started.wait(timeout=10.0)
    # While the fit runs, parameter services and a second ~/learn are answered at once.
    params = r.probe.create_client(GetParameters, "/learner/get_parameters")
    assert params.wait_for_service(timeout_sec=5.0)
    got = params.call_async(GetParameters.Request(names=["sigma"]))
    second = r.client.call_async(Trigger.Request())
    end = time.monotonic() + 1.0
    while not (got.done() and second.done()) and time.monotonic() < end:
        time.sleep(0.01)
    assert got.done() and got.result().values[0].string_value == "medium"
    # Refused at once, not queued behind the running fit.
    assert second.done() and not second.result().success
    assert not first.done()
    end = time.monotonic() + 60.0
    while not first.done() and time.monotonic() < end:
        time.sleep(0.01)
    assert first.result().success


def test_sigma_parameter_is_validated(rig, tmp_path):
    r = rig(164)
    assert not r.node.set_parameters([Parameter("sigma", value="huge")])[0].successful
    assert r.node.set_parameters([Parameter("sigma", value="0.5")])[0].successful
    assert parse_sigma("Narrow") == "narrow" and parse_sigma("0.25") == 0.25
    with pytest.raises(ValueError, match=r"^sigma\b.*'-1'"):
        parse_sigma("-1")


def test_sigma_as_a_number_is_accepted_at_start_up_and_at_run_time(rig, tmp_path):
    # config/learner.yaml documents "sigma^2 as a number": YAML and -p sigma:=0.5 give a
    # DOUBLE (or INTEGER), which a STRING-typed parameter refused, failing the start-up.
    _write_dataset(tmp_path / "demos", n_demos=6)
    r = rig(167, dataset_dir=str(tmp_path / "demos"), model_path=str(tmp_path / "m.npz"),
            sigma=0.5)
    assert r.node.get_parameter("sigma").value == 0.5
    response = r.learn()
    assert response.success, response.message
    assert r.node.last_result.summary["sigma2"] == 0.5
    assert r.node.set_parameters([Parameter("sigma", value=2)])[0].successful
    for bad in (True, -1.0, ["medium"], None):  # None: unset, which would undeclare it
        assert not r.node.set_parameters([Parameter("sigma", value=bad)])[0].successful
    assert r.node.get_parameter("sigma").value == 2


def test_observed_ncpe_is_zero_for_the_true_policy_and_positive_otherwise():
    rng = np.random.default_rng(1)
    trajs = []
    for _ in range(5):
        alpha = rng.normal(size=3)
        N = np.eye(3) - np.outer(alpha, alpha) / (alpha @ alpha)
        x, X = rng.normal(size=3), []
        for _ in range(30):
            X.append(x.copy())
            x = x + 0.01 * (N @ -x)
        trajs.append(Trajectory(np.array(X), np.arange(30) * 0.01))
    assert observed_ncpe(lambda X: -X, trajs) < 1e-10
    assert observed_ncpe(lambda X: X, trajs) > 1.0


def test_robot_config_names_the_models_robot_and_joints(rig, tmp_path):
    arm = ["shoulder_pan_joint", "elbow_joint"]  # two of ur5's joints, recorded reversed
    _write_dataset(tmp_path / "demos", joints=arm[::-1])
    config = tmp_path / "arm.yaml"
    config.write_text(f"robot: ur5\njoints: [{arm[0]}, {arm[1]}]\n")
    model = tmp_path / "model.npz"
    r = rig(199, dataset_dir=str(tmp_path / "demos"), model_path=str(model),
            robot_config=str(config))
    response = r.learn()
    assert response.success, response.message
    learnt = PolicyAlign.load(model)
    assert learnt.robot_ == "ur5" and learnt.joint_names_ == arm  # the config's order
    # A robot the demonstrations' joints are not joints of: refused, naming the robot and
    # the joint, and no model file naming a robot the executor could not load.
    _write_dataset(tmp_path / "other", joints=JOINTS)
    results = r.node.set_parameters([
        Parameter("dataset_dir", value=str(tmp_path / "other")),
        Parameter("model_path", value=str(tmp_path / "other.npz")),
        Parameter("robot_config", value=""), Parameter("robot", value="ur5")])
    assert all(result.successful for result in results)
    response = r.learn()
    assert not response.success and "'ur5'" in response.message and "j1" in response.message
    assert not (tmp_path / "other.npz").exists()


def test_plot_path_draws_each_fit_and_a_bad_one_does_not_fail_the_learning(rig, tmp_path):
    _write_dataset(tmp_path / "demos")
    figure = tmp_path / "fit.png"
    r = rig(231, dataset_dir=str(tmp_path / "demos"), model_path=str(tmp_path / "model.npz"),
            plot_path=str(figure))
    response = r.learn()
    assert response.success and str(figure) in response.message
    assert figure.read_bytes()[:4] == b"\x89PNG"
    # A figure that cannot be written is said, and the model is still the answer.
    result = r.node.set_parameters([Parameter("plot_path", value="fit.jpeg")])[0]
    assert not result.successful and "plot_path" in result.reason and "'jpeg'" in result.reason
    blocked = tmp_path / "model.npz" / "fit.png"  # under a file
    assert r.node.set_parameters([Parameter("plot_path", value=str(blocked))])[0].successful
    response = r.learn()
    assert response.success and str(blocked) in response.message  # said, not failed
    assert not blocked.exists()


_LoggedLearner = logged(Learner)


class _LoggedRig(Rig):
    node_class = _LoggedLearner


def test_fit_warnings_and_a_refusal_are_logged_once_through_the_logger(tmp_path,
                                                                        monkeypatch):
    rng = np.random.default_rng(3)
    for k in range(7):  # random walks: refused as no better than a zero policy, with warnings
        X = np.cumsum(rng.normal(scale=0.05, size=(60, 2)), axis=0)
        stamps = 10**18 + k * 10**10 + np.arange(60) * 50_000_000
        write_joint_state_bag(tmp_path / "walks" / f"demo_{k:04d}", JOINTS, stamps, X)
    real = learner_module.learn_pipeline

    def noisy_pipeline(*args, **kwargs):
        # numpy's overflow and invalid value, as inside a fit, and a warning said twice.
        with np.errstate(over="warn", invalid="warn"):
            for _ in range(3):
                np.exp(np.full(4, 1000.0))
            np.log(np.full(2, -1.0))
        for _ in range(2):
            warnings.warn("the same fit warning twice", UserWarning, stacklevel=1)
        return real(*args, **kwargs)

    monkeypatch.setattr(learner_module, "learn_pipeline", noisy_pipeline)
    r = _LoggedRig(217, dataset_dir=str(tmp_path / "walks"), model_path=str(tmp_path / "m"))
    try:
        with warnings.catch_warnings(record=True) as escaped:
            warnings.simplefilter("always")
            response = r.learn()
        result = r.node.last_result
        records = list(r.node.log.records)
    finally:
        r.close()
    assert not response.success and result.refused
    # Nothing reached Python's warning output (stderr, with a source file and line).
    assert not [w for w in escaped if issubclass(w.category, (UserWarning, RuntimeWarning))]
    # The refusal: one record, at ERROR (the pipeline also says it as progress).
    refusal = [(level, m) for level, m in records if result.line() in m]
    assert [level for level, _ in refusal] == ["error"]
    said = [m for level, m in records if level == "warning"]
    assert len(said) == len(set(said))  # each text once
    assert said.count("the same fit warning twice") == 1
    # Besides those two, the fit's own (worse than a zero policy warns), by the logger.
    assert result.summary["worse_than_zero"] and len(said) >= 3
    numerical = [m for m in said if "overflow" in m]
    assert len(numerical) == 1 and re.search(r"\b4\b", numerical[0])  # 3 overflows, 1 invalid
