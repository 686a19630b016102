"""The ``policy-align`` command: ``demo``, ``learn``, ``show``, ``call``, ``param`` and
``bench``, each importing its heavy dependencies only when it runs. Their options:
``policy-align COMMAND --help``, and ``docs/design.md`` section 7.
"""

from __future__ import annotations

import argparse
import sys


def _add_bench(sub) -> None:
    """The ``bench`` sub-command and its options (shared, suite-only and lasa-only)."""
    bench = sub.add_parser("bench", help="reproduce the paper's experiments, measure speed")
    bench.add_argument("which",
                       choices=["toy", "grasp", "humanoid", "scale", "executor", "suite",
                                "lasa"])
    bench.add_argument("--datasets", type=int, default=None,
                       help="data sets per cell; executor: trajectories; scale: repeats "
                            "(default: the paper's number, or 100 and 3)")
    bench.add_argument("--jobs", type=int, default=2, help="worker processes")
    bench.add_argument("--out", default="bench_out", help="directory for tables and figures")
    bench.add_argument("--seed", type=int, default=0, help="base random seed")
    bench.add_argument("--cases", default=None,
                       help="suite only: comma-separated case names (default: all)")
    bench.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                       help="suite: a TrendKernelRegression parameter of the new model "
                            "(repeatable), e.g. offset_ridge=inf, for ablations; lasa: a "
                            "PolicyAlign or TrendKernelRegression parameter")
    bench.add_argument("--noise", type=float, default=0.0, metavar="F",
                       help="suite only: white noise on the recorded positions of the "
                            "training demonstrations, of RMS norm F median steps per sample")
    bench.add_argument("--demos", type=int, default=None, metavar="K",
                       help="suite: K training demonstrations per data set instead of "
                            "the case's own number; lasa: the first K of each shape's 7")
    bench.add_argument("--max-extrapolation-rad", type=float, default=None, metavar="R",
                       help="suite only: the extrapolation guard's cap for the guarded runs "
                            "(rad; default the executor's, 0.5)")
    bench.add_argument("--protocol", default="both", choices=("loo", "all", "both"),
                       help="lasa only: leave one demonstration out, train on all 7, or both")
    bench.add_argument("--shapes", default="all",
                       help="lasa only: tuning, reporting, all (the 26 single-pattern shapes), "
                            "multi (the 4 multi-pattern ones) or comma-separated names")
    bench.add_argument("--methods", default=None, type=lambda s: s.split(","),
                       help="lasa only: comma-separated subset of policy_align,naive,gmr,"
                            "grad_field (default: all four)")
    bench.add_argument("--recorded", action="store_true",
                       help="lasa only: train on the demonstrations as a recorder stores "
                            "them: at rest before and after the motion, with position noise")
    bench.add_argument("--hesitant", action="store_true",
                       help="lasa only: each training demonstration stops once on the way "
                            "for 0.3-1 s, as a teacher who hesitates")
    bench.add_argument("--scattered-ends", action="store_true",
                       help="lasa only: each training demonstration ends where a teacher "
                            "stops, 2 %% of the workspace apart (per coordinate, random)")
    bench.add_argument("--subsample", type=int, default=None, metavar="N",
                       help="lasa only: train on every N-th sample (default 5, the "
                            "protocol's; 1 is the data set's own rate, 115-520 Hz)")


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="policy-align",
        description="Learn potential-based policies from constrained demonstrations "
        "(PolicyAlign) and execute them under new constraints.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="run the whole ROS 2 graph on a simulated robot")
    demo.add_argument("--robot", default="talos",
                      help="robot config (talos, panda, ur5 or a .yaml path), or an "
                           "example-robot-data name or URDF (all joints, no frames)")
    demo.add_argument("--out", default="demo_out", help="directory for data, model, plots")
    demo.add_argument("--state", default="joints", choices=("joints", "hands"),
                      help="learn in joint space or in the positions of both hands")
    demo.add_argument("--seed", type=int, default=0,
                      help="seed of every random draw (demonstrations, starts, hold-out)")

    learn = sub.add_parser("learn", help="learn a model from rosbag2 bags or datasets")
    learn.add_argument("inputs", nargs="+", metavar="BAG_OR_DATASET")
    learn.add_argument("--out", required=True, help="model file to write (.npz)")
    learn.add_argument("--joints", default=None, help="comma-separated joint names")
    learn.add_argument("--sigma", default="medium", help="narrow|medium|wide or sigma^2")
    learn.add_argument("--gap", type=float, default=0.5, help="split demos at gaps [s]")
    learn.add_argument("--robot", default=None,
                       help="example-robot-data name or URDF the demonstrations were "
                            "recorded on (stored in the model; needed for --state frames:; "
                            "its continuous joints are unwrapped onto one turn)")
    learn.add_argument("--robot-config", default=None,
                       help="robot config (talos, panda, ur5 or a .yaml path): its robot, "
                            "and its joints unless --joints is given")
    learn.add_argument("--state", default="joints",
                       help="joints (default) or frames:F1,F2 (stacked frame positions)")
    learn.add_argument("--holdout", type=float, default=0.2,
                       help="fraction of demonstrations held out to score the fit, in "
                            "[0, 0.5] (the learner node's holdout_fraction range)")
    learn.add_argument("--seed", type=int, default=0, help="seed of the split and the fit")
    learn.add_argument("--force", action="store_true",
                       help="write the model even if the fit is refused as degenerate")
    learn.add_argument("--plot", default=None, metavar="FIG.png",
                       help="also draw the fit (also when refused; .png, .pdf or .svg): "
                            "the potential along each demonstration, runs from their "
                            "starts, held-out error per fold, the states")
    learn.add_argument("--overwrite", action="store_true",
                       help="replace an --out model learnt for other joints or another "
                            "state (one of the same joints is replaced without it)")
    learn.add_argument("--min-sigma2-fraction", type=float, default=None,
                       help="refuse sigma^2 below this fraction of the data variance "
                            "(default 1e-4)")
    learn.add_argument("--max-discarded-fraction", type=float, default=None,
                       help="refuse when more demonstrations are too weakly connected to "
                            "align (default 0.5)")
    learn.add_argument("--heldout-tolerance", type=float, default=None,
                       help="refuse a held-out nCPE above the current model's + this "
                            "(default 0.02)")
    learn.add_argument("--duplicate-tol", type=float, default=None,
                       help="relative distance under which demonstrations are duplicates "
                            "(default 1e-3)")

    show = sub.add_parser("show", help="what a model file holds: robot, joints, the learn "
                                       "summary, refusals, the learnt goal")
    show.add_argument("model", metavar="MODEL", help="model file (.npz)")
    show.add_argument("--json", action="store_true", help="print it as JSON")

    call = sub.add_parser("call", help="call a std_srvs Trigger or SetBool service")
    call.add_argument("service", help="for example /learner/learn")
    call.add_argument("--data", choices=["true", "false"], default=None,
                      help="SetBool request value (omit for Trigger)")
    call.add_argument("--timeout", type=float, default=30.0, help="seconds to wait")

    param = sub.add_parser("param", help="get or set a parameter of a running node")
    param.add_argument("action", choices=["get", "set"])
    param.add_argument("node", help="node name, for example /executor")
    param.add_argument("name", help="parameter name, for example max_velocity")
    param.add_argument("value", nargs="?", default=None,
                       help="set only: the value, read as the parameter's type")
    param.add_argument("--timeout", type=float, default=10.0, help="seconds to wait")

    _add_bench(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``policy-align``; returns the process exit code."""
    args = _build_parser().parse_args(argv)
    try:
        if args.command == "bench":
            from policy_align_ros.experiments.bench import run_bench

            return run_bench(args)
        if args.command == "learn":
            from policy_align_ros.data.learn import run_learn

            return run_learn(args)
        if args.command == "show":
            from policy_align_ros.data.show import run_show

            return run_show(args)
        if args.command == "demo":
            from policy_align_ros.client.demo import run_demo

            return run_demo(args)
        if args.command == "call":
            from policy_align_ros.client.call import run_call

            return run_call(args)
        if args.command == "param":
            from policy_align_ros.client.param import run_param

            return run_param(args)
    except KeyboardInterrupt:
        return 130
    except (ValueError, FileNotFoundError) as err:
        print(f"policy-align {args.command}: error: {err}", file=sys.stderr)
        return 2
    return 2


if __name__ == "__main__":
    sys.exit(main())
