"""Robustness cases of the executor: enable without a model, bad constraints and models,
broken joint states while armed, a clock that jumps back, bad start-up parameters."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from robustness_harness import ARM, MS, Lab, Result
from robustness_rigs import (
    NodeRig,
    duration,
    node_start,
    param_case,
    rig_case,
    service_case,
    start_refused,
)

from policy_align_ros.control import ZeroCause
from policy_align_ros.polling import wait_for

#: The causes of a disarm by joint states that stopped (or stopped advancing).
_STALE = (ZeroCause.STALE_STATE, ZeroCause.FROZEN_STAMP)


def _fit_model(path: Path, joints: Sequence[str], center: np.ndarray) -> Path:
    """A PolicyAlign model on ``joints`` of 8 demonstrations converging to ``center``."""
    from policy_align_ros.learning import PolicyAlign, Trajectory

    rng = np.random.default_rng(0)
    t = np.arange(40) * 0.05
    trajs = []
    for _ in range(8):
        q0 = center + rng.normal(scale=0.3, size=len(joints))
        trajs.append(Trajectory(center + (q0 - center) * np.exp(-t)[:, None], t))
    PolicyAlign(sigma="medium").fit(trajs, joint_names=list(joints)).save(path)
    return path


STATE_TIMEOUT_S = 2.0


class _Feeder:
    """Publishes valid joint states (node-clock stamps) every 20 ms while on."""

    def __init__(self, rig: NodeRig, joints: Sequence[str], q: np.ndarray) -> None:
        from sensor_msgs.msg import JointState

        self.rig, self.joints, self.q = rig, list(joints), q
        self._type = JointState
        self.last_stamp = None  # of the last message published by the thread
        # Stamping and publishing happen under one lock, for the thread's messages and for
        # inject()'s: otherwise a message stamped just before an injected valid one could
        # be published after it and read, rightly, as a stamp going backwards.
        self._lock = threading.Lock()
        self._on = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def message(self, names=None, positions=None, stamp=None):
        msg = self._type(name=list(self.joints if names is None else names),
                         position=[float(v) for v in (self.q if positions is None
                                                      else positions)])
        msg.header.stamp = (self.rig.node.get_clock().now().to_msg() if stamp is None
                            else stamp)
        return msg

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            if self._on.is_set() and self.rig.context.ok():
                with self._lock:
                    msg = self.message()
                    self.rig.publish(self._type, "/joint_states", msg)
                    self.last_stamp = msg.header.stamp

    def inject(self, make_msg) -> None:
        """Publish ``make_msg()`` on the feeder's topic, ordered with the feeder's own."""
        with self._lock:
            self.rig.publish(self._type, "/joint_states", make_msg())

    def on(self) -> None:
        self._on.set()

    def off(self) -> None:
        self._on.clear()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)



def _enable(rig: NodeRig, on: bool = True) -> Any:
    """Call the executor's ``~/enable``; the response, or None."""
    from std_srvs.srv import SetBool

    return rig.call(SetBool, "/executor/enable", SetBool.Request(data=on))


def _executor_parameters(lab: Lab, base: dict, work: Path, other: Path) -> list[Result]:
    """Without a model: ``~/enable`` refused, and bad parameters set at run time."""
    from policy_align_ros.nodes.executor import Executor

    out: list[Result] = []
    p = param_case
    rig = NodeRig(lab, Executor, dict(base))
    try:
        out.append(service_case(rig, "exe-enable-without-model",
                                "executor `~/enable true` with no model",
                                lambda: _enable(rig), False, "no model"))
        out.append(p(rig, "exe-constraints-bad-yaml",
                     "executor `constraints: '[{type: plane, frame: arm_left_7_link'`",
                     "constraints", "[{type: plane, frame: arm_left_7_link", "constraints"))
        out.append(p(rig, "exe-constraints-unknown-frame",
                     "executor `constraints` on frame `no_such_link`", "constraints",
                     "[{type: plane, frame: no_such_link, normal: [0, 0, 1]}]",
                     "no_such_link"))
        out.append(p(rig, "exe-constraints-normal-length",
                     "executor plane constraint with `normal: [0, 1]` (2 values)",
                     "constraints", "[{type: plane, frame: arm_left_7_link, normal: [0, 1]}]",
                     "normal"))
        out.append(p(rig, "exe-constraints-zero-normal",
                     "executor plane constraint with `normal: [0, 0, 0]`", "constraints",
                     "[{type: plane, frame: arm_left_7_link, normal: [0, 0, 0]}]", "normal"))
        out.append(p(rig, "exe-constraints-unknown-type", "executor `constraints: "
                     "[{type: cylinder}]`", "constraints", "[{type: cylinder}]", "cylinder"))
        out.append(p(rig, "exe-constraints-not-a-list", "executor `constraints: '42'`",
                     "constraints", "42", "constraints"))
        out.append(p(rig, "exe-constraints-wrong-type", "executor `constraints: "
                     "[{type: joints, joints: 3}]` (a number for the joint list)",
                     "constraints", "[{type: joints, joints: 3}]", "non-empty list"))
        out.append(p(rig, "exe-max-velocity-nan", "executor `max_velocity: nan`",
                     "max_velocity", float("nan")))
        out.append(p(rig, "exe-max-velocity-negative", "executor `max_velocity: -1.0`",
                     "max_velocity", -1.0))
        out.append(p(rig, "exe-max-acceleration-inf", "executor `max_acceleration: inf`",
                     "max_acceleration", float("inf")))
        out.append(p(rig, "exe-model-path-missing", "executor `model_path` to a missing file",
                     "model_path", str(work / "missing.npz"), "missing.npz"))
        out.append(p(rig, "exe-model-path-not-a-model", "executor `model_path` to a text file",
                     "model_path", str(work / "notes.txt"), "notes.txt"))
        out.append(p(rig, "exe-model-path-other-joints",
                     "executor `model_path` to a model of joints a, b", "model_path",
                     str(other), "model"))
        out.append(p(rig, "exe-robot-read-only", "executor `robot: panda` at run time",
                     "robot", "panda", "read-only"))
        out.append(p(rig, "exe-joints-read-only", "executor `joints` changed at run time",
                     "joints", ARM[::-1], "read-only"))
        out.append(p(rig, "exe-controller-bad-name", "executor `controller: 'no such//node'`",
                     "controller", "no such//node", "controller"))
    finally:
        rig.close()
    return out


class _ArmedCases:
    """Cases on an executor with a model, fed valid joint states by a ``_Feeder``."""

    def __init__(self, rig: NodeRig, feeder: _Feeder, commands: list[np.ndarray],
                 out: list[Result]) -> None:
        self.rig, self.exe, self.feeder = rig, rig.node, feeder
        self.commands, self.out = commands, out

    def state_case(self, case: str, tried: str, make_msg: Callable[[], Any], disarms: bool,
                   reason: str | None = None) -> Result:
        """``make_msg()`` sent to the armed executor: it disarms, or is ignored (counted as
        ``reason``), or accepted (``reason`` None)."""
        exe = self.exe
        # A message may meet a disarm it did not cause: on an overloaded machine the
        # feeder thread can stall past state_timeout_s, or one of its valid states arrive
        # that long after its stamp (stamp_too_old), and a disarm is
        # silent until the next enable, so the message's own reason is then never seen.
        # Or it may never arrive: a subscriber stalled for 0.2 s drops it from its queue
        # of 10 under the feeder's 50 Hz (still armed, no counter moved). None says
        # anything about the message, so the case is tried again (at most twice); an
        # executor that mishandles the message fails every attempt.
        for _ in range(3):
            r = self._attempt(case, tried, make_msg, disarms, reason)
            disarmed = not exe.controller.armed
            stale = disarmed and (exe.controller.zero_cause in _STALE or not disarms)
            unseen = disarms and not disarmed and not r.data.get("counted")
            if not (stale or unseen):
                break
        self.out.append(r)
        return r

    def _attempt(self, case: str, tried: str, make_msg: Callable[[], Any], disarms: bool,
                 reason: str | None) -> Result:
        rig, exe, commands, feeder = self.rig, self.exe, self.commands, self.feeder
        r = Result(case, "messages", tried)
        armed = wait_for(lambda: _enable(rig).success and exe.controller.armed, 10.0)
        wait_for(lambda: len(commands) > 0 and np.abs(commands[-1]).max() > 0, 10.0)
        if not r.expect(armed, "could not arm before the case"):
            return r
        with rig_case(r, rig):
            rejected = sum(exe.rejected_states.values())
            before = dict(exe.rejected_states)
            n = len(commands)
            feeder.inject(make_msg)
            if disarms:
                # With a reason, its count too: the disarm can be seen before the count.
                wait_for(lambda: not exe.controller.armed and any(
                    not c.any() for c in commands[n:]) and (
                        reason is None or sum(exe.rejected_states.values()) > rejected), 5.0)
            elif reason is not None:
                wait_for(lambda: sum(exe.rejected_states.values()) > rejected, 5.0)
                time.sleep(0.2)
            else:
                time.sleep(0.3)  # accepted: nothing to wait for but a few ticks
        zero = any(not c.any() for c in commands[n:])
        counted = sum(exe.rejected_states.values()) - rejected
        r.data.update(armed=exe.controller.armed, zero=zero, counted=counted,
                      rejected=dict(exe.rejected_states))
        reasons = ", ".join(f"`{k}`" for k, v in exe.rejected_states.items()
                            if v > before.get(k, 0)) or "nothing"
        if disarms:
            r.behaviour = ("rejected, zero command at once, disarmed until `~/enable`"
                           if zero and not exe.controller.armed else
                           f"armed={exe.controller.armed}, zero command={zero}")
            r.expect(not exe.controller.armed, "still armed after the message")
            r.expect(zero, "no zero command after the message")
        elif reason is None:
            r.behaviour = f"accepted (matched by name), still armed={exe.controller.armed}"
            r.expect(exe.controller.armed, "disarmed by a valid message")
            r.expect(counted == 0, "a valid message was rejected")
        else:
            r.behaviour = (f"ignored and counted, still armed={exe.controller.armed}")
            r.expect(exe.controller.armed, "disarmed by a message meant for someone else")
        if reasons != "nothing" or reason is not None:
            r.behaviour += f"; counted as {reasons}"
        if not disarms and not exe.controller.armed:  # why, for a failure to say
            cause = exe.controller.zero_cause
            r.behaviour += (f"; disarmed: {cause.value if cause else 'none'}: "
                            f"{exe.controller.zero_reason}")
        if reason is not None:
            r.expect(exe.rejected_states.get(reason, 0) > 0, f"not counted as {reason}")
        return r

    def announce(self, case: str, tried: str, path: Path) -> None:
        """``/learner/model`` announcing ``path``, a file that must not load."""
        from std_msgs.msg import String

        rig, exe = self.rig, self.exe
        r = Result(case, "messages", tried)
        with rig_case(r, rig):
            before = exe.model_path
            rig.publish(String, "/learner/model", String(data=str(path)))
            time.sleep(1.0)  # a refusal changes nothing, so there is nothing to wait for
        r.behaviour = ("refused (logged); the loaded model stays" if
                       exe.model_path == before else f"loaded {exe.model_path}")
        r.expect(exe.model_path == before, "the model changed")
        self.out.append(r)


def _bad_states(cases: _ArmedCases, feeder: _Feeder, center: np.ndarray) -> None:
    """Broken joint states to the armed executor (and two it must accept or ignore)."""
    from builtin_interfaces.msg import Time
    from rclpy.time import Time as RclpyTime

    state_case = cases.state_case
    q = center + 0.2
    now = cases.exe.get_clock().now
    state_case("exe-msg-joint-twice", "JointState naming arm_left_1_joint twice (the "
               "second with another value), executor armed",
               lambda: feeder.message(ARM + [ARM[0]], list(q) + [q[0] + 0.5]), True,
               "duplicate_joints")
    state_case("exe-msg-nan", "JointState with a NaN position, executor armed",
               lambda: feeder.message(positions=[np.nan] + list(q[1:])), True,
               "non_finite")
    state_case("exe-msg-lengths", "JointState with 7 names and 6 positions, armed",
               lambda: feeder.message(positions=list(q[:6])), True, "length_mismatch")
    state_case("exe-msg-stamp-old", "JointState stamped 10 s ago, armed",
               lambda: feeder.message(stamp=(now() - duration(10.0)).to_msg()), True)
    state_case("exe-msg-stamp-zero", "JointState with a zero stamp, armed",
               lambda: feeder.message(stamp=Time()), True)
    state_case("exe-msg-stamp-future", "JointState stamped 10 s in the future, armed",
               lambda: feeder.message(stamp=(now() + duration(10.0)).to_msg()), True)
    # Before the feeder's last stamp, not the clock's: on a loaded machine the feeder
    # thread can fall more than 0.3 s behind, and "now - 0.3 s" is then in order.
    state_case("exe-msg-stamp-backwards", "JointState stamped 0.3 s before the last one",
               lambda: feeder.message(stamp=(RclpyTime.from_msg(feeder.last_stamp)
                                             - duration(0.3)).to_msg()), True)
    state_case("exe-msg-other-joints", "JointState of other joints only (another "
               "publisher), armed", lambda: feeder.message(["x1", "x2"], [0.0, 0.0]),
               False, "unknown_joints")
    state_case("exe-msg-extra-joint", "JointState with the 7 joints and 2 more (another "
               "order), armed", lambda: feeder.message(
                   ["x1"] + ARM[::-1] + ["x2"], [0.0] + list(q[::-1]) + [0.0]), False)
    state_case("exe-msg-missing-joint", "JointState with 6 of the 7 joints, armed",
               lambda: feeder.message(ARM[:6], list(q[:6])), False, "missing_joints")


def _executor_armed_cases(lab: Lab, base: dict, work: Path, model: Path, other: Path,
                          center: np.ndarray) -> list[Result]:
    """With a model: broken joint states while armed, stale states, bad announcements."""
    from std_msgs.msg import Float64MultiArray

    from policy_align_ros.nodes.executor import Executor

    out: list[Result] = []
    s = service_case
    # follow_learner: the announcements below must be tried, not ignored for model_path.
    rig = NodeRig(lab, Executor, dict(base, model_path=str(model), follow_learner=True))
    commands: list[np.ndarray] = []
    rig.probe.create_subscription(Float64MultiArray, "/velocity_controller/commands",
                                  lambda m: commands.append(np.array(m.data)), 1000)
    feeder = _Feeder(rig, ARM, center + 0.2)
    try:
        exe = rig.node
        out.append(s(rig, "exe-enable-no-joint-states",
                     "executor `~/enable true` with a model but no joint state yet",
                     lambda: _enable(rig), False, "refused"))
        feeder.on()
        cases = _ArmedCases(rig, feeder, commands, out)
        _bad_states(cases, feeder, center)
        announce = cases.announce
        feeder.off()
        wait_for(lambda: not exe.controller.armed, 3.0 * STATE_TIMEOUT_S)  # states went stale
        time.sleep(STATE_TIMEOUT_S + 0.1)  # longer than state_timeout_s without a state
        out.append(s(rig, "exe-enable-stale-states",
                     f"executor `~/enable true` {STATE_TIMEOUT_S + 0.1:.1f} s after the last "
                     f"joint state (`state_timeout_s` {STATE_TIMEOUT_S})", lambda: _enable(rig),
                     False, "refused"))
        feeder.on()
        announce("exe-announce-missing-model", "`/learner/model` announcing a missing file",
                 work / "missing.npz")
        announce("exe-announce-not-a-model", "`/learner/model` announcing a text file",
                 work / "notes.txt")
        announce("exe-announce-other-joints", "`/learner/model` announcing a model of "
                 "joints a, b", other)
    finally:
        feeder.close()
        rig.close()
    return out


def cases_executor(lab: Lab) -> list[Result]:
    """executor: enable without a model, bad constraints and models, broken joint states."""
    from policy_align_ros.kinematics import Robot

    work = lab.path("executor")
    center = Robot.load("talos", ARM).neutral()
    model = _fit_model(work / "model.npz", ARM, center)
    other = _fit_model(work / "other.npz", ["a", "b"], np.zeros(2))
    (work / "notes.txt").write_text("not a model\n")
    # 2 s, not the default 0.5 s: on a loaded 2-core machine the feeder thread can stall
    # for most of a second, which would disarm for staleness in the middle of a case
    # about something else.
    # No stall detection: the fed joint states never move, whatever the commands.
    base = {"robot": "talos", "joints": ARM, "rate_hz": 50.0,
            "state_timeout_s": STATE_TIMEOUT_S, "max_acceleration": 5.0, "controller": "",
            "stall_time_s": 0.0}
    out = _executor_parameters(lab, base, work, other)
    out += _executor_armed_cases(lab, base, work, model, other, center)
    out.append(_executor_clock_jump(lab, base, model, center))
    if not lab.start_ups:
        return out
    for case, tried, args, needle in (
            ("exe-start-unknown-robot", "`executor -p robot:=no_such_robot`",
             ["-p", "robot:=no_such_robot"], "no_such_robot"),
            ("exe-start-unknown-joint", "`executor -p 'joints:=[arm_left_1_joint, nope]'`",
             ["-p", "joints:=[arm_left_1_joint, nope]"], "nope"),
            ("exe-start-joints-repeated",
             "`executor -p 'joints:=[arm_left_1_joint, arm_left_1_joint]'`",
             ["-p", "joints:=[arm_left_1_joint, arm_left_1_joint]"], "joints"),
            ("exe-start-bad-constraints", "`executor -p 'constraints:=[{type: plane'`",
             ["-p", "constraints:=[{type: plane"], "constraints"),
            ("exe-start-joints-empty", "`executor -p 'joints:=[]'`",
             ["-p", "joints:=[]"], "non-empty list"),
            ("exe-start-model-missing", "`executor -p model_path:=/nonexistent/model.npz`",
             ["-p", "model_path:=/nonexistent/model.npz"], "nonexistent")):
        r = Result(case, "parameters", tried)
        start_refused(r, node_start(lab, "executor", *args), needle)
        out.append(r)
    return out


def _executor_clock_jump(lab: Lab, base: dict, model: Path, center: np.ndarray) -> Result:
    """An armed executor on sim time whose ``/clock`` jumps 10 s back (a restarted sim)."""
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64MultiArray

    from policy_align_ros.nodes.executor import Executor

    r = Result("exe-clock-jumps-back", "messages",
               "`/clock` jumps 10 s back while the executor (use_sim_time) is armed")
    rig = NodeRig(lab, Executor, dict(base, model_path=str(model), use_sim_time=True))
    commands: list[np.ndarray] = []
    rig.probe.create_subscription(Float64MultiArray, "/velocity_controller/commands",
                                  lambda m: commands.append(np.array(m.data)), 1000)
    sim_ns = [1_000 * 10**9]
    stop = threading.Event()

    def tick():  # the simulated clock: 20 ms of sim time every 20 ms
        from rclpy.time import Time

        while not stop.wait(0.02):
            sim_ns[0] += 20 * MS
            if rig.context.ok():
                rig.publish(Clock, "/clock", Clock(clock=Time(nanoseconds=sim_ns[0]).to_msg()))

    clock = threading.Thread(target=tick, daemon=True)
    clock.start()
    feeder = _Feeder(rig, ARM, center + 0.2)
    try:
        exe = rig.node
        wait_for(lambda: exe.get_clock().now().nanoseconds > 1_000 * 10**9, 10.0)
        feeder.on()
        armed = wait_for(lambda: _enable(rig).success, 10.0)
        wait_for(lambda: len(commands) > 0 and np.abs(commands[-1]).max() > 0, 10.0)
        if r.expect(armed and exe.controller.armed, "could not arm before the case"):
            with rig_case(r, rig):
                n = len(commands)
                sim_ns[0] -= 10 * 10**9
                wait_for(lambda: not exe.controller.armed and any(
                    not c.any() for c in commands[n:]), 5.0)
            zero = any(not c.any() for c in commands[n:])
            r.behaviour = ("zero command at once, disarmed until `~/enable`"
                           if zero and not exe.controller.armed else
                           f"armed={exe.controller.armed}, zero command={zero}")
            r.expect(not exe.controller.armed, "still armed after the clock jumped back")
            r.expect(zero, "no zero command after the jump")
    finally:
        stop.set()
        clock.join(timeout=2.0)
        feeder.close()
        rig.close()
    return r
