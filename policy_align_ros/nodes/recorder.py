"""``recorder`` node: record ``/joint_states`` into one rosbag2 bag per demonstration.

Thin adapter around :class:`policy_align_ros.data.recording.DemoRecorder`: converts
``sensor_msgs/msg/JointState`` (header stamp in ns, falling back to the node clock when
zero; positions in rad or m, velocities in rad/s or m/s) to plain values, declares and
validates the parameters, and offers the services.

Interface (docs/design.md section 6):

* subscribes ``/joint_states`` (reliable, keep-last ``qos_depth``, 10 s at 1 kHz by default,
  so a burst is queued rather than lost while a bag is being written);
* services ``~/start_demo`` and ``~/stop_demo`` (``std_srvs/srv/Trigger``); ``stop_demo``
  first records the joint states still queued (they arrived before the request), and
  answers once the bag is complete on disk, with its path as the message (followed by a
  warning, after "; ", when the robot did not move during the demonstration: every joint
  within ``STILL_TOLERANCE`` of its first sample; the bag is written all the same).
  Without a demonstration to end (no ``start_demo`` before it) it answers
  ``success=false``, naming the fix; so it does, writing nothing, when the stamps jumped
  back by ``CLOCK_RESET_S`` or more during the demonstration (a simulator reset): kept, it
  would be spliced across the reset;
* parameters ``dataset_dir`` (str), ``joints`` (str[], unset = those of the first
  message), ``auto_split_gap_s`` (s, 0 = manual mode; otherwise recording starts at once
  and splits at gaps), ``qos_depth`` (read-only), ``warn_period_s``. Changes at run time
  are validated (``SetParametersResult(successful=False, reason=...)`` on bad values) and
  apply to the next bag; ``joints`` cannot change while a demonstration is buffered, and
  changing ``auto_split_gap_s`` changes the splitting, not whether recording is on
  (leaving continuous mode writes the demonstration recorded so far).

Failures lose no finished demonstration:

* ``dataset_dir`` is created and probed for writing at start-up; if it cannot be written
  (under a file, read-only, no permission) the node does not start: it prints
  ``error: dataset_dir: ...`` and exits with status 1 (:func:`run_node`), without a traceback,
  because a recorder that cannot record should fail where it is launched rather than
  when a demonstration ends. A change at run time is checked the same way and refused
  with that reason.
* A demonstration whose write fails later (full disk, EFBIG, permission, the directory
  replaced) is kept in memory, at most one: ``stop_demo`` answers ``success=false`` with
  the reason and an error is logged; ``start_demo`` is refused with the reason while it is
  pending; a continuous recording pauses (the messages dropped meanwhile are counted in the
  throttled warning). It is written by the next ``stop_demo`` or by the retry every
  ``_RETRY_PERIOD_S`` of node time, once the directory works (e.g. after fixing it or
  setting ``dataset_dir``).
* On shutdown (SIGINT, SIGTERM) the pending demonstration and a continuous recording's
  last segment are written; if ``dataset_dir`` still fails they go to the first working
  fallback directory (``$ROS_HOME/policy_align_recorder/unsaved``, else under the temp
  dir; see :func:`~policy_align_ros.data.dataset_dir.default_fallback_dirs`), named in an
  error log line. An unfinished manual demonstration (``stop_demo`` never called) is
  discarded with a warning.
* On SIGKILL the demonstration in progress (and a pending one) is lost and every earlier
  bag is intact (bags are renamed into place only when complete).

Skipped (malformed) messages are reported in a warning at most every ``warn_period_s``.
A header stamp more than ``_MAX_STAMP_AHEAD_S`` after the node clock is skipped as
``time_in_future`` (a stray stamp must not make the rest of a demonstration look like time
going backwards); not with ``use_sim_time``, where both come from ``/clock``. A negative
stamp (``sec < 0``, a publisher whose clock was never set) is skipped as
``time_negative``; only a zero stamp means "unstamped" and gets the node clock.

No error escapes a callback or :meth:`RecorderNode.shutdown`: an exception leaving a
callback would end the spin, and with it the recording and the retries of a pending
demonstration. A write that fails with any exception is handled as a failed write above.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from policy_align_ros.data.dataset_dir import check_dataset_dir, default_fallback_dirs
from policy_align_ros.data.messages import (
    describe_foreign,
    describe_skips,
    validate_joint_names,
)
from policy_align_ros.data.recording import DemoRecorder, PendingWriteError, validate_gap
from policy_align_ros.kinematics.robot_config import load_robot_config
from policy_align_ros.nodes._common import StartNode, run_node

__all__ = ["RecorderNode", "main"]

_MAX_GAP_S = 3600.0
# A failed write is retried this often [s of node time]: rare enough that a full disk is not
# hammered with a bag that is written and deleted again, soon enough to resume promptly.
_RETRY_PERIOD_S = 5.0
# Tolerated lead of a header stamp over the node clock [s]: synchronised clocks on a robot
# network agree to milliseconds, and a stray stamp can spoil at most this much recording.
_MAX_STAMP_AHEAD_S = 1.0


class RecorderNode(StartNode):
    """Record joint-state demonstrations; see the module docstring for the interface."""

    def __init__(self, **kwargs) -> None:
        super().__init__("recorder", **kwargs)
        self.declare_parameter("dataset_dir", "demos", ParameterDescriptor(
            description="directory receiving one rosbag2 bag (demo_NNNN) per demonstration"))
        joints = self.declare_parameter("joints", Parameter.Type.STRING_ARRAY, ParameterDescriptor(
            description="recorded joints, in order; unset or empty: those of the first "
            "message"))
        config = self.declare_parameter("robot_config", "", ParameterDescriptor(
            description="robot config (talos, panda, ur5 or a .yaml path) whose joints are "
            "recorded when joints is unset; empty = none", read_only=True))
        recorded = joints.value or (load_robot_config(config.value).joints
                                    if config.value else None)
        self.declare_parameter("auto_split_gap_s", 0.0, ParameterDescriptor(
            description="0: manual mode (~/start_demo, ~/stop_demo); > 0: record "
            "continuously and split demonstrations at time gaps longer than this [s]",
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=_MAX_GAP_S)]))
        self.declare_parameter("warn_period_s", 5.0, ParameterDescriptor(
            description="minimum time between warnings about skipped messages [s]",
            floating_point_range=[FloatingPointRange(from_value=0.1, to_value=3600.0)]))
        depth = self.declare_parameter("qos_depth", 10000, ParameterDescriptor(
            description="subscription queue depth (reliable, keep last)", read_only=True,
            integer_range=[IntegerRange(from_value=1, to_value=1_000_000, step=1)]))
        self._recorder = DemoRecorder(
            self.get_parameter("dataset_dir").value,
            joints=validate_joint_names(recorded),
            auto_split_gap_s=self.get_parameter("auto_split_gap_s").value,
            topic=self.resolve_topic_name("/joint_states"),
            max_stamp_ahead_s=_MAX_STAMP_AHEAD_S,
        )
        self.add_on_set_parameters_callback(self._on_set_parameters)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth.value,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.subscription = self.create_subscription(
            JointState, "/joint_states", self._on_joint_state, qos)
        self.create_service(Trigger, "~/start_demo", self._on_start)
        self.create_service(Trigger, "~/stop_demo", self._on_stop)
        self.create_timer(0.1, self._on_timer)
        self._reported_skips = 0
        self._last_warning: int | None = None  # node-clock ns
        self._last_retry: int | None = None
        if self._recorder.auto_split_gap_s > 0:
            self._recorder.start(self._now_s())
        self.get_logger().info(
            f"recording into {self._recorder.dataset_dir} "
            + ("continuously, split at gaps of "
               f"{self._recorder.auto_split_gap_s} s" if self._recorder.active
               else "on ~/start_demo")
        )

    @property
    def recorder(self) -> DemoRecorder:
        """The ROS-free recorder (for inspection)."""
        return self._recorder

    def _now_s(self) -> float:
        """Node-clock time [s]: idle splitting follows sim time when use_sim_time is set."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_joint_state(self, msg: JointState) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        now = self.get_clock().now().nanoseconds
        chosen = self._recorder.joints is not None
        try:
            path = self._recorder.add(stamp or now, msg.name, msg.position, msg.velocity,
                                      msg.effort, now=now * 1e-9,
                                      clock_ns=self._future_check_clock(now))
        except PendingWriteError as err:
            self._last_retry = now  # a failure starts the retry period
            self.get_logger().error(f"{err}; recording paused until it is written")
            return
        except Exception as err:  # never out of a callback: see the module docstring
            # Throttled: an unexpected error would otherwise repeat at the stream's rate.
            self.get_logger().error(
                f"could not record a message: {type(err).__name__}: {err}",
                throttle_duration_sec=self.get_parameter("warn_period_s").value)
            return
        if not chosen and self._recorder.joints is not None:
            # Said once: another publisher's joints on the topic would be recorded instead.
            self.get_logger().info(
                f"recording joints {', '.join(self._recorder.joints)}: those of the first "
                "message (set joints or robot_config to choose them)")
        if path is not None:
            self._said_written(path, f"demonstration written (time gap): {path}")

    def _future_check_clock(self, now: int) -> int | None:
        """The clock to check stamps against for ``time_in_future``, or None for no check.

        With use_sim_time the stamps and this clock come from the same ``/clock``, whose
        delivery can lag the joint states by many simulated seconds at a high real-time
        factor, so a lead says nothing about the stamp; before the first ``/clock`` the
        clock reads 0.
        """
        if now <= 0 or self.get_clock().ros_time_is_active:
            return None
        return now

    def _on_start(
        self, request: Trigger.Request, response: Trigger.Response
    ) -> Trigger.Response:
        try:
            self._recorder.start(self._now_s())
        except RuntimeError as err:
            response.success, response.message = False, str(err)
            return response
        response.success, response.message = True, "recording"
        return response

    def _on_stop(
        self, request: Trigger.Request, response: Trigger.Response
    ) -> Trigger.Response:
        if not self._recorder.stoppable:
            response.success = False
            response.message = ("not recording: call ~/start_demo first, then ~/stop_demo "
                                "ends the demonstration and writes it")
            return response
        if self._recorder.active:
            self._drain()
        count = self._recorder.pending or self._recorder.buffered
        try:
            path = self._recorder.stop()
        except Exception as err:  # never out of a callback: see the module docstring
            self._last_retry = self.get_clock().now().nanoseconds
            self.get_logger().error(f"stop_demo: writing failed: {err}")
            response.success, response.message = False, f"writing failed: {err}"
            return response
        if path is None and self._recorder.last_discard:
            response.success = False
            response.message = (f"discarded, not written: {self._recorder.last_discard}; "
                                f"record this demonstration again")
            self.get_logger().warning(f"stop_demo: {response.message}")
        elif path is None:
            response.success = False
            response.message = f"nothing written: {count} valid message(s) recorded"
            foreign = self._foreign()
            if foreign and not count:
                response.message += f" ({foreign})"
        else:
            response.success, response.message = True, str(path)
            still = self._said_written(path, f"demonstration written: {path} ({count} "
                                             "messages)")
            if still:
                response.message += f"; {still}"
        return response

    def _said_written(self, path: Path, text: str) -> str:
        """Log ``text``, that the bag ``path`` was written; with a warning when the robot
        did not move during it, which is returned ("" otherwise)."""
        if path not in self._recorder.still_bags:
            self.get_logger().info(text)
            return ""
        still = (f"warning: the robot did not move during this demonstration (every joint "
                 f"within {self._recorder.still_tolerance:g} of its first sample); written "
                 "anyway")
        self.get_logger().warning(f"{text}; {still}")
        return still

    def _drain(self) -> None:
        """Record the joint states already queued when ``stop_demo`` is served.

        The executor takes one message per subscription between other callbacks, so a
        backlog (a loaded machine, a burst) would still be queued when the request is
        served and then be dropped; those messages arrived before the request and belong
        to the demonstration. At most ``qos_depth`` are taken, the queue's own bound.
        """
        sub = self.subscription
        try:
            with sub.handle:
                for _ in range(self.get_parameter("qos_depth").value):
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
                    if taken is None:
                        return
                    self._on_joint_state(taken[0])
        except Exception as err:  # never out of a callback: see the module docstring
            self.get_logger().error(f"stop_demo: could not take the queued joint states: "
                                    f"{type(err).__name__}: {err}")

    def _set_gap(self, gap: float) -> None:
        """Apply ``auto_split_gap_s``; leaving continuous mode writes the current segment."""
        try:
            path = self._recorder.set_auto_split_gap(gap)
        except PendingWriteError as err:  # the gap is set; the timer retries the write
            self.get_logger().error(f"{err}; recording paused until it is written")
            self._last_retry = self.get_clock().now().nanoseconds
            return
        if path is not None:
            self._said_written(path, f"demonstration written (continuous mode ended): {path}")

    def _on_timer(self) -> None:
        now = self.get_clock().now().nanoseconds
        self._flush_if_idle(now)
        self._retry_if_due(now)
        self._warn_skips(now)

    def _flush_if_idle(self, now: int) -> None:
        """Write a continuous recording's segment once the stream went idle."""
        try:
            path = self._recorder.flush_if_idle(now * 1e-9)
        except Exception as err:  # never out of a callback: see the module docstring
            self.get_logger().error(f"could not write a demonstration: {err}")
            self._last_retry = now
            path = None
        if path is not None:
            self._said_written(path, f"demonstration written (stream idle): {path}")

    def _retry_if_due(self, now: int) -> None:
        """Retry writing a pending demonstration every ``_RETRY_PERIOD_S``."""
        # A clock that jumped back (a restarted sim publishing /clock) also allows a retry.
        if self._recorder.pending and (
                self._last_retry is None or not 0 <= now - self._last_retry
                < _RETRY_PERIOD_S * 1e9):
            self._last_retry = now
            count = self._recorder.pending
            try:
                path = self._recorder.retry_pending()
            except Exception as err:  # never out of a callback: see the module docstring
                self.get_logger().error(f"retry failed: {err}")
            else:
                self._said_written(
                    path, f"pending demonstration written: {path} ({count} messages)"
                    + ("; recording resumed" if self._recorder.active else ""))

    def _foreign(self) -> str:
        """What the last message skipped for its joints lacks of the recorded joints and
        carries ("" before there is one)."""
        joints, names = self._recorder.joints, self._recorder.last_foreign
        if not joints or names is None:
            return ""
        return (f"the last message skipped for its joints, recording "
                f"{', '.join(joints)}: {describe_foreign(joints, names)}")

    def _warn_skips(self, now: int) -> None:
        skipped = self._recorder.skipped
        lost = self._recorder.lost_while_pending
        total = sum(skipped.values()) + lost
        period_ns = self.get_parameter("warn_period_s").value * 1e9
        if total == self._reported_skips or (
                self._last_warning is not None and 0 <= now - self._last_warning < period_ns):
            return
        detail = describe_skips(skipped, lost)
        foreign = self._foreign()
        if foreign and (skipped["unknown_joints"] or skipped["missing_joints"]):
            detail += f"; {foreign}"
        self.get_logger().warning(
            f"skipped {total - self._reported_skips} joint_states message(s) "
            f"since the last report ({total} in total: {detail})"
        )
        self._reported_skips, self._last_warning = total, now

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        try:
            for param in params:
                if param.name == "dataset_dir":
                    if param.type_ != Parameter.Type.STRING:
                        raise ValueError("dataset_dir: must be a string")
                    check_dataset_dir(param.value)
                elif param.name == "joints":
                    if param.type_ not in (Parameter.Type.STRING_ARRAY, Parameter.Type.NOT_SET):
                        raise ValueError("joints: must be a list of strings")
                    validate_joint_names(param.value or None)
                    if self._recorder.buffered:
                        raise ValueError("joints: cannot change while a demonstration is "
                                         "recorded")
                elif param.name == "auto_split_gap_s":
                    validate_gap(param.value)
            # Validated as a whole first, so that a rejected set changes nothing.
            for param in params:
                if param.name == "dataset_dir":
                    self._recorder.set_dataset_dir(param.value)
                elif param.name == "joints":
                    self._recorder.set_joints(param.value or None)
                elif param.name == "auto_split_gap_s":
                    self._set_gap(param.value)
        except (TypeError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def shutdown(self) -> None:
        """Finish cleanly: save a pending demonstration and a continuous recording's last
        segment (to a fallback directory if need be); drop an unfinished manual one.

        Never raises: every outcome is logged.
        """
        keep = self._recorder.auto_split_gap_s > 0
        unfinished = 0 if keep else self._recorder.buffered
        logger = self.get_logger()
        try:
            results = self._recorder.close(keep_current=keep,
                                           fallback_dirs=default_fallback_dirs())
        except Exception as err:  # close() catches write errors; this is the last resort
            logger.error(f"saving at shutdown failed: {type(err).__name__}: {err}")
            results = []
        for result in results:
            if result.path is None:
                logger.error(
                    f"LOST a demonstration of {result.messages} messages: no directory "
                    f"could be written ({'; '.join(result.errors)})")
            elif result.fallback:
                logger.error(
                    f"demonstration of {result.messages} messages written to the FALLBACK "
                    f"directory {result.path} because dataset_dir failed "
                    f"({'; '.join(result.errors)}); move it into the dataset")
            else:
                self._said_written(result.path,
                                   f"demonstration written at shutdown: {result.path}")
        if unfinished:
            logger.warning(
                f"discarded an unfinished demonstration of {unfinished} messages "
                "(~/stop_demo was not called)")


def main(args: list[str] | None = None) -> int:
    """Console script ``recorder``: :func:`run_node`'s stop flag, then :meth:`shutdown`
    saves what is left before the node is destroyed (while the context is still valid)."""
    return run_node(RecorderNode, args, finish=RecorderNode.shutdown)


if __name__ == "__main__":
    sys.exit(main())
