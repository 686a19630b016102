"""Robustness cases of the recorder: bad parameters, malformed joint states, services out of
order, a dataset directory that disappears and a clock that restarts. Nothing recorded may
be lost."""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from robustness_harness import J2, Lab, Result, short
from robustness_rigs import (
    NodeRig,
    duration,
    node_start,
    param_case,
    rig_case,
    service_case,
    start_refused,
    trigger,
)

from policy_align_ros.polling import wait_for


def _joint_state(rig: NodeRig, names: Sequence[str], pos: Sequence[float],
                 vel: Sequence[float] = (), stamp: Any = None) -> Any:
    """A ``JointState``, stamped with the node clock unless ``stamp`` is given."""
    from sensor_msgs.msg import JointState

    msg = JointState(name=list(names), position=[float(v) for v in pos],
                     velocity=[float(v) for v in vel])
    msg.header.stamp = (rig.node.get_clock().now().to_msg() if stamp is None
                        else stamp)
    return msg


def _recorder_parameters(rig: NodeRig, work: Path) -> list[Result]:
    """Bad values set at run time: each refused with a reason, the node unharmed."""
    p = param_case
    return [
        p(rig, "rec-dataset-dir-under-file",
          "recorder `dataset_dir` set at run time to a path under a file",
          "dataset_dir", str(work / "a_file" / "demos"), "dataset_dir"),
        p(rig, "rec-dataset-dir-empty", "recorder `dataset_dir: ''`",
          "dataset_dir", "", "dataset_dir"),
        p(rig, "rec-joints-repeated", "recorder `joints: [j1, j1]`",
          "joints", ["j1", "j1"], "j1"),
        p(rig, "rec-joints-empty-name", "recorder `joints: [j1, '']`",
          "joints", ["j1", ""], "joint"),
        p(rig, "rec-gap-nan", "recorder `auto_split_gap_s: nan`",
          "auto_split_gap_s", float("nan")),
        p(rig, "rec-gap-negative", "recorder `auto_split_gap_s: -1.0`",
          "auto_split_gap_s", -1.0),
        p(rig, "rec-gap-wrong-type", "recorder `auto_split_gap_s: 'fast'` (string)",
          "auto_split_gap_s", "fast"),
        p(rig, "rec-qos-depth-read-only", "recorder `qos_depth: 5` at run time",
          "qos_depth", 5),
        p(rig, "rec-warn-period-zero", "recorder `warn_period_s: 0.0`",
          "warn_period_s", 0.0),
    ]


class _MessageCases:
    """Bad joint states sent to a recording recorder, each between good ones."""

    def __init__(self, rig: NodeRig, out: list[Result]) -> None:
        self.rig, self.rec, self.out = rig, rig.node.recorder, out
        self.good_sent = 0

    def send_good(self, n: int = 2) -> None:
        """Publish ``n`` valid joint states, each waited for until recorded."""
        from sensor_msgs.msg import JointState

        rec = self.rec
        for _ in range(n):
            target = rec.accepted + 1
            self.rig.publish(JointState, "/joint_states",
                             _joint_state(self.rig, J2, [0.1 * self.good_sent, 0.2]))
            self.good_sent += 1
            wait_for(lambda t=target: rec.accepted >= t, 10.0)

    def case(self, case: str, tried: str, make_msg: Callable[[], Any],
             reason: str | None) -> Result:
        """``make_msg()`` between good messages: skipped as ``reason`` (None: recorded)."""
        from sensor_msgs.msg import JointState

        rig, rec = self.rig, self.rec
        self.send_good()
        r = Result(case, "messages", tried)
        with rig_case(r, rig):
            skipped, accepted = sum(rec.skipped.values()), rec.accepted
            # Built now: a stamp taken before the good messages would be "backwards".
            rig.publish(JointState, "/joint_states", make_msg())
            if reason is None:
                wait_for(lambda: rec.accepted > accepted, 10.0)
            else:
                wait_for(lambda: rec.skipped[reason] > 0 and
                         sum(rec.skipped.values()) > skipped, 10.0)
            self.send_good(1)  # the stream goes on after the bad message
        new_skips = {k: v for k, v in rec.skipped.items() if v} if reason else {}
        if reason is None:
            r.expect(rec.accepted >= accepted + 2, "a valid message was not recorded")
        else:
            r.behaviour = f"skipped and counted as `{reason}` ({rec.skipped[reason]})"
            r.expect(sum(rec.skipped.values()) == skipped + 1,
                     f"not skipped as {reason}: {new_skips}")
            r.expect(rec.accepted == accepted + 1,
                     "the valid message after it was not recorded")
        r.data["skipped"] = dict(rec.skipped)
        self.out.append(r)
        return r


def _message_cases(rig: NodeRig, out: list[Result]) -> None:
    """The malformed joint states, appended to ``out`` (a demonstration is recording)."""
    from builtin_interfaces.msg import Time

    cases = _MessageCases(rig, out)
    msg_case = cases.case

    def state(*args, **kw):
        return _joint_state(rig, *args, **kw)

    now = rig.node.get_clock().now
    msg_case("rec-msg-missing-joint", "JointState with j1 only (recorder selects j1, j2)",
             lambda: state(["j1"], [0.1]), "missing_joints")
    r = msg_case("rec-msg-extra-joint", "JointState with an extra joint j3",
                 lambda: state(["j3", "j2", "j1"], [9.0, 0.2, 0.1]), None)
    r.behaviour = "recorded: j1, j2 matched by name, j3 ignored"
    msg_case("rec-msg-empty", "JointState with empty name/position arrays",
             lambda: state([], []), "unknown_joints")
    msg_case("rec-msg-lengths", "JointState with 2 names and 1 position",
             lambda: state(J2, [0.1]), "length_mismatch")
    msg_case("rec-msg-nan", "JointState with a NaN position", lambda: state(J2, [np.nan, 0.2]),
             "non_finite")
    msg_case("rec-msg-inf-velocity", "JointState with an inf velocity",
             lambda: state(J2, [0.1, 0.2], [np.inf, 0.0]), "non_finite")
    msg_case("rec-msg-joint-twice", "JointState naming j1 twice (other values)",
             lambda: state(["j1", "j2", "j1"], [0.1, 0.2, 0.7]), "duplicate_joints")
    msg_case("rec-msg-stamp-backwards", "JointState stamped 5 s before the last one",
             lambda: state(J2, [0.1, 0.2], stamp=(now() - duration(5.0)).to_msg()),
             "time_not_increasing")
    r = msg_case("rec-msg-stamp-zero", "JointState with a zero header stamp",
                 lambda: state(J2, [0.1, 0.2], stamp=Time()), None)
    r.behaviour = "recorded, stamped with the node clock (unstamped message)"
    r = msg_case("rec-msg-stamp-future", "JointState stamped 1 h in the future",
                 lambda: state(J2, [0.1, 0.2], stamp=(now() + duration(3600.0)).to_msg()),
                 "time_in_future")
    before = rig.node.recorder.accepted
    cases.send_good(3)
    r.expect(rig.node.recorder.accepted == before + 3,
             "valid messages after the future stamp are not recorded")
    msg_case("rec-msg-stamp-negative", "JointState stamped before the epoch (sec = -1)",
             lambda: state(J2, [0.1, 0.2], stamp=Time(sec=-1)), "time_negative")


def _stop_and_count_lost(rig: NodeRig, out: list[Result]) -> None:
    """Stop the demonstration: every valid message must be in its bag (else one is lost)."""
    from policy_align_ros.data import load_dataset

    accepted = rig.node.recorder.accepted
    response = trigger(rig, "/recorder/stop_demo")
    ok = response is not None and response.success
    written = 0
    if ok:
        trajs, _, _ = load_dataset(response.message, gap_s=0.0)
        written = sum(len(t.positions) for t in trajs)
    for row in out:
        if row.area == "messages":
            row.lost = 0 if ok and written == accepted else 1
            row.data.update(written=written, accepted=accepted)


def _recorder_rig_cases(lab: Lab, work: Path) -> list[Result]:
    """Parameters, services out of order and malformed messages, on one recorder."""
    from sensor_msgs.msg import JointState

    from policy_align_ros.nodes.recorder import RecorderNode

    out: list[Result] = []
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(work / "demos"), "joints": J2})
    try:
        out.extend(_recorder_parameters(rig, work))
        s = service_case
        out.append(s(rig, "rec-stop-without-start", "recorder `~/stop_demo` with no start",
                     lambda: trigger(rig, "/recorder/stop_demo"), False))
        first = trigger(rig, "/recorder/start_demo")
        out.append(s(rig, "rec-start-twice", "recorder `~/start_demo` twice in a row",
                     lambda: trigger(rig, "/recorder/start_demo"), False, "already"))
        out[-1].expect(first is not None and first.success, "the first start_demo failed")
        _message_cases(rig, out)
        out.append(param_case(rig, "rec-joints-while-recording",
                              "recorder `joints: [j2, j1]` while a demonstration is recorded",
                              "joints", ["j2", "j1"], "joints"))
        _stop_and_count_lost(rig, out)
        out.append(s(rig, "rec-stop-nothing-valid",
                     "recorder `~/start_demo` then `~/stop_demo` with no valid message",
                     lambda: (trigger(rig, "/recorder/start_demo"),
                              rig.publish(JointState, "/joint_states",
                                          _joint_state(rig, ["j1"], [0.0])),
                              time.sleep(0.2),
                              trigger(rig, "/recorder/stop_demo"))[-1], False, "nothing"))
    finally:
        rig.close()
    return out


def cases_recorder(lab: Lab) -> list[Result]:
    """The recorder: bad parameters, malformed joint states, services out of order."""
    work = lab.path("recorder")
    (work / "a_file").write_text("x")
    out = _recorder_rig_cases(lab, work)
    out.append(_recorder_dir_replaced(lab, work))
    out.append(_recorder_clock_restart(lab, work))
    if not lab.start_ups:
        return out
    # Start-up: a recorder that cannot write its dataset must not start.
    run = node_start(lab, "recorder", "-p", f"dataset_dir:={work / 'a_file' / 'demos'}")
    r = Result("rec-start-dir-under-file", "parameters",
               "`recorder --ros-args -p dataset_dir:=A_FILE/demos` (start-up)")
    start_refused(r, run, "dataset_dir")
    out.append(r)
    run = node_start(lab, "recorder", "-p", f"dataset_dir:={work / 'ok'}",
                     "-p", "joints:=[j1, j1]")
    r = Result("rec-start-joints-repeated", "parameters",
               "`recorder --ros-args -p 'joints:=[j1, j1]'` (start-up)")
    start_refused(r, run, "j1")
    out.append(r)
    return out


# --- write failures ---------------------------------------------------------------------
def _ramp_state(rig: NodeRig, k: int, offset_s: float = 0.0) -> Any:
    """The ``k``-th state of a ramp on ``J2``, stamped ``offset_s`` from the node clock."""
    stamp = (rig.node.get_clock().now() + duration(offset_s)).to_msg()
    return _joint_state(rig, J2, [0.01 * k, -0.01 * k], stamp=stamp)


def _messages_in(directory: Path) -> int:
    """Joint states in the bags of ``directory`` (0 when there is none)."""
    from policy_align_ros.data import find_bags, load_dataset

    bags = find_bags(directory) if directory.is_dir() else []
    if not bags:
        return 0
    trajs, _, _ = load_dataset(directory, gap_s=0.0)
    return sum(len(t.positions) for t in trajs)


def _recorder_dir_replaced(lab: Lab, work: Path) -> Result:
    """A dataset directory replaced by a file mid-demo: the demonstration stays pending and
    is written to the next ``dataset_dir``."""
    from sensor_msgs.msg import JointState

    from policy_align_ros.nodes.recorder import RecorderNode

    demos = work / "replaced"
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(demos), "joints": J2})
    r = Result("rec-dataset-dir-replaced", "services",
               "recorder: `dataset_dir` replaced by a file during a demonstration, then "
               "`~/stop_demo`, `~/start_demo`, `dataset_dir` set to a new directory, "
               "`~/stop_demo`")
    try:
        rec = rig.node.recorder
        with rig_case(r, rig):
            trigger(rig, "/recorder/start_demo")
            for k in range(10):
                rig.publish(JointState, "/joint_states", _ramp_state(rig, k))
            wait_for(lambda: rec.accepted >= 10, 10.0)
            shutil.rmtree(demos)
            demos.write_text("in the way\n")
            stop = trigger(rig, "/recorder/stop_demo")
            start = trigger(rig, "/recorder/start_demo")
            moved = rig.set_param("dataset_dir", str(work / "moved"))
            again = trigger(rig, "/recorder/stop_demo")
        answers = [stop, start, again]
        if r.expect(all(a is not None for a in answers), "a service did not answer"):
            r.behaviour = (f"stop: success={str(stop.success).lower()} "
                           f"({short(stop.message, 150)}); start: "
                           f"success={str(start.success).lower()}; after the new "
                           f"dataset_dir, stop: success={str(again.success).lower()} "
                           "(the 10 messages written)")
            r.expect(not stop.success, "the failed write was not reported")
            r.expect(not start.success,
                     "start_demo not refused while a demonstration is pending")
            r.expect(moved[0] and again.success, "the pending demonstration was not written")
        written = _messages_in(work / "moved")
        r.lost = 0 if written == 10 else 1
        r.data["written"] = written
    finally:
        rig.close()
    return r


def _recorder_clock_restart(lab: Lab, work: Path) -> Result:
    """Continuous recording whose stamps jump back: split, and nothing lost at shutdown."""
    from sensor_msgs.msg import JointState

    from policy_align_ros.data import find_bags
    from policy_align_ros.nodes.recorder import RecorderNode

    cont = work / "continuous"
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(cont), "joints": J2,
                                      "auto_split_gap_s": 0.5})
    r = Result("rec-continuous-clock-restart", "messages",
               "recorder in continuous mode: the stamps jump 100 s back mid-stream (a "
               "restarted simulation), then the node is shut down")
    try:
        rec = rig.node.recorder
        with rig_case(r, rig):
            for k in range(10):
                rig.publish(JointState, "/joint_states", _ramp_state(rig, k))
            wait_for(lambda: rec.accepted >= 10, 10.0)
            for k in range(10):
                rig.publish(JointState, "/joint_states", _ramp_state(rig, k, offset_s=-100.0))
            wait_for(lambda: rec.accepted >= 20, 10.0)
    finally:
        rig.close()  # shutdown() writes the last segment of a continuous recording
    bags = find_bags(cont) if cont.is_dir() else []
    written = _messages_in(cont)
    r.behaviour = (f"split into {len(bags)} demonstrations ({written} of 20 messages "
                   "written; the last at shutdown)")
    r.expect(len(bags) == 2, f"{len(bags)} bags, expected 2")
    r.lost = 0 if written == 20 else 1
    return r
