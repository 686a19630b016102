"""``policy-align demo``: the whole ROS 2 graph on a simulated robot, on simulated time.

Notation: ``q`` joint positions (rad), ``x`` the learning state: ``x = q`` for
``--state joints``, or the stacked positions (m) of both hands (``arm_left_7_link``,
``arm_right_7_link``) for ``--state hands``; ``x_c`` the expert's goal (its attractor in
joint space, the hand targets in hand space). Times are seconds of simulated time unless
called wall time.

Stages (each one failing makes the command exit with status 1):

1. start ``sim_robot`` (publishing ``/clock`` at ``real_time_factor`` times real time),
   ``recorder``, ``learner``, ``executor`` and ``demonstrator`` as separate processes on
   ``ROS_DOMAIN_ID`` when set, else a private ROS domain, all with ``use_sim_time``;
   parameters in ``OUT/params.yaml``, logs in ``OUT/logs/``;
2. the demonstrator records ``demos`` demonstrations of its expert (joint space:
   ``pi(q) = -gain (q - q_c)``; hand space: ``pi_x = -gain (x - x_c)`` realised through the
   Jacobian) with the robot config's constraint frames (Talos: both hands; Panda, UR5:
   the tool) on planes of random orientation, re-drawn twice per demonstration;
3. ``/learner/learn`` fits PolicyAlign on all but a held-out share, draws the fit in
   ``OUT/demo_fit.png`` (the learner's ``plot_path``, ``docs/design/fit_figure.md``) and
   announces the model; what was used, held out and discarded is read from the model
   file's header;
4. the learnt policy is scored with the paper's nCPE on fresh demonstrations generated
   offline, whose projectors ``N`` are known (``heldout_ncpe_fresh``);
5. the executor drives the simulated robot from *new* start states drawn from the
   demonstrations' start distribution (a separate random stream; each is checked to be
   away from every recorded demonstration's start): ``free_runs`` unconstrained runs and
   ``held_runs`` runs under the robot config's ``unseen_constraint``, never demonstrated
   (Talos: the left hand held in place; Panda, UR5: the tool held in place).
   Every run lasts ``run_duration_s``; the goal of a run is the point the expert reaches
   from the same start under the same constraint (integrated offline until it settles),
   and the expert's own distance to it after ``run_duration_s`` is reported beside the
   learnt policy's;
6. ``OUT/report.json`` (docs/design.md section 7) is written; the printed report (also
   ``OUT/report.txt``) and the plots ``OUT/demo_distance.png`` and ``OUT/demo_hands.png``
   are made from it and the traces in ``OUT/traces.npz``.

Simulated time: ``sim_robot`` advances ``/clock`` one period (``1 / rate_hz``) per tick,
``real_time_factor`` ticks per period of wall time; the demonstrator steps in lockstep
with the joint states (its command for tick ``i + 1`` comes from the state of tick ``i``),
and so does the executor (``step_on_joint_state``). A *missed control period* is a tick
whose joint velocity equals the previous tick's (non-zero), i.e. the simulator integrated a
command it had already used; the report's ``sim`` block counts them for the executor runs
and the recorded demonstrations.

The exit status is also 1 when an unconstrained run does not end closer to its goal than
it started. Missed targets are reported (``targets`` in the report) without changing
the status. Every child process is stopped (SIGINT, then SIGKILL) whatever happens. All
randomness derives from ``--seed``.

Modules: :mod:`.settings` (settings, random streams), :mod:`.task` (learning state, expert,
new starts), :mod:`.graph` (node processes, parameters file), :mod:`.conductor` (the node
talking to the graph), :mod:`.periods` (missed control periods), :mod:`.stages` (the run
schedule), :mod:`.report` (run entries, targets, report), :mod:`.plots` (figures) and
:mod:`.main` (the entry point).
"""

from policy_align_ros.client.demo.main import run_demo
from policy_align_ros.client.demo.report import report_text
from policy_align_ros.client.demo.settings import DemoSettings, StageError

__all__ = ["DemoSettings", "StageError", "report_text", "run_demo"]
