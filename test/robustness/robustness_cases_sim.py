"""Robustness cases of the simulation nodes: ``sim_robot`` (commands it cannot apply, bad
parameters, an unknown robot) and the ``demonstrator`` (parameters, no recorder)."""

from __future__ import annotations

import numpy as np
from robustness_harness import ARM, Lab, Result
from robustness_rigs import NodeRig, node_start, param_case, rig_case, start_refused

from policy_align_ros.polling import wait_for


def cases_sim_robot(lab: Lab) -> list[Result]:
    """sim_robot: commands it cannot apply, bad parameters, an unknown robot."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from policy_align_ros.nodes.sim_robot import SimRobot

    out: list[Result] = []
    rig = NodeRig(lab, SimRobot, {"joints": ARM, "command_timeout_s": 5.0})
    states: list[JointState] = []
    rig.probe.create_subscription(JointState, "/joint_states", states.append, 100)
    try:
        sim = rig.node

        def command_case(case, tried, data):
            r = Result(case, "messages", tried)
            wait_for(lambda: len(states) > 0, 10.0)
            with rig_case(r, rig):
                start = np.array(sim.sim.q)
                bad = sim._bad_commands
                rig.publish(Float64MultiArray, "/velocity_controller/commands",
                            Float64MultiArray(data=[float(v) for v in data]))
                wait_for(lambda: sim._bad_commands > bad, 10.0)
                n = len(states)
                wait_for(lambda: len(states) >= n + 5, 10.0)  # a few integration steps
                moved = float(np.abs(np.array(sim.sim.q) - start).max())
            r.data.update(bad=sim._bad_commands - bad, moved=moved)
            r.behaviour = (f"ignored and counted ({sim._bad_commands} so far, warned at most "
                           f"every 2 s); the joints moved {moved:.3g} rad")
            r.expect(sim._bad_commands == bad + 1, "the command was not counted as ignored")
            r.expect(moved == 0.0, "the robot moved on a command it should ignore")
            out.append(r)

        command_case("sim-cmd-wrong-length", "Float64MultiArray of 3 values to a 7-joint "
                     "sim_robot", [0.1, 0.1, 0.1])
        command_case("sim-cmd-nan", "Float64MultiArray with a NaN velocity",
                     [float("nan")] + [0.0] * 6)
        command_case("sim-cmd-inf", "Float64MultiArray with an inf velocity",
                     [float("inf")] + [0.0] * 6)
        command_case("sim-cmd-empty", "an empty Float64MultiArray", [])
        p = param_case
        out.append(p(rig, "sim-initial-positions-length",
                     "sim_robot `initial_positions` with 3 values for 7 joints",
                     "initial_positions", [0.0, 0.0, 0.0], "initial_positions"))
        out.append(p(rig, "sim-initial-positions-nan", "sim_robot `initial_positions` with NaN",
                     "initial_positions", [float("nan")] + [0.0] * 6, "initial_positions"))
        out.append(p(rig, "sim-command-timeout-nan", "sim_robot `command_timeout_s: nan`",
                     "command_timeout_s", float("nan")))
        out.append(p(rig, "sim-command-timeout-zero", "sim_robot `command_timeout_s: 0.0`",
                     "command_timeout_s", 0.0))
        out.append(p(rig, "sim-rate-read-only", "sim_robot `rate_hz: 10.0` at run time",
                     "rate_hz", 10.0, "read-only"))
    finally:
        rig.close()
    if not lab.start_ups:
        return out
    r = Result("sim-start-unknown-robot", "parameters",
               "`sim_robot --ros-args -p robot:=no_such_robot` (start-up)")
    start_refused(r, node_start(lab, "sim_robot", "-p", "robot:=no_such_robot"),
                   "no_such_robot")
    out.append(r)
    r = Result("sim-start-unknown-joint", "parameters",
               "`sim_robot --ros-args -p 'joints:=[arm_left_1_joint, no_such_joint]'`")
    start_refused(r, node_start(lab, "sim_robot", "-p",
                                 "joints:=[arm_left_1_joint, no_such_joint]"),
                   "no_such_joint")
    out.append(r)
    r = Result("sim-start-joints-empty", "parameters", "`sim_robot --ros-args -p 'joints:=[]'`")
    start_refused(r, node_start(lab, "sim_robot", "-p", "joints:=[]"), "at least one joint")
    out.append(r)
    return out



def cases_demonstrator(lab: Lab) -> list[Result]:
    """demonstrator: parameters at run time and at start-up, no recorder to bracket demos."""
    from policy_align_ros.nodes.demonstrator import Demonstrator

    out = []
    rig = NodeRig(lab, Demonstrator, {"joints": ARM, "constraint_frames": ["arm_left_7_link"],
                                      "service_timeout_s": 600.0})
    try:
        out.append(param_case(rig, "demo-gain-read-only", "demonstrator `gain: 5.0` at run "
                               "time (read-only)", "gain", 5.0, "read-only"))
        out.append(param_case(rig, "demo-num-demos-wrong-type",
                               "demonstrator `num_demos: 'many'` (string)", "num_demos",
                               "many"))
    finally:
        rig.close()
    if not lab.start_ups:
        return out
    for case, tried, args, needle in (
            ("demo-start-attractor-length", "`demonstrator -p 'attractor:=[0.0, 0.0]'` "
             "(18 joints)", ["-p", "attractor:=[0.0, 0.0]"], "attractor"),
            ("demo-start-unknown-frame", "`demonstrator -p 'constraint_frames:=[no_frame]'`",
             ["-p", "constraint_frames:=[no_frame]"], "no_frame"),
            ("demo-start-no-recorder", "`demonstrator` with no recorder running "
             "(`service_timeout_s:=1.0`)", ["-p", "service_timeout_s:=1.0"], "recorder")):
        r = Result(case, "parameters" if "recorder" not in case else "services", tried)
        start_refused(r, node_start(lab, "demonstrator", *args), needle)
        out.append(r)
    return out


