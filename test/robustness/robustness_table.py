#!/usr/bin/env python3
"""Robustness table: bad inputs against the CLI, bags, parameters, messages and services.

Runs the case groups of ``robustness_cases_*.py`` and prints (or writes into
``docs/robustness.md``) one row per bad input. Columns of the table (``--markdown``):

* *crash*: the process died from an uncaught exception or a signal, a node callback raised,
  a service never answered, or a node stopped answering;
* *traceback*: ``Traceback (most recent call last)`` appeared in the output;
* *demos lost*: recorded messages missing from the bags on disk (recorder), or good
  demonstrations silently left out of a model that was written (bags); ``-`` when no
  demonstration is involved;
* *verdict*: ``ok``, or what differs from what a robot owner expects.

Usage::

    python test/robustness/robustness_table.py                  # everything, print the table
    python test/robustness/robustness_table.py --markdown docs/robustness.md
    python test/robustness/robustness_table.py --only cli,bags  # groups (cli = cli-learn, ...)
    python test/robustness/robustness_table.py --in-process     # CLI through cli.main (faster)

ROS cases run in-process, each rig with its own ``rclpy.Context`` on its own DDS domain
(``--domain-base``, default 60: ids 60-99; ``test_robustness.py`` uses 130-142); node
start-up cases and, by default, CLI cases run as subprocesses of this interpreter's
environment.
"""

from __future__ import annotations

import shutil
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

from robustness_cases_bags import cases_bags
from robustness_cases_cli import cases_cli_demo, cases_cli_learn, cases_cli_misc, cases_cli_ros
from robustness_cases_executor import cases_executor
from robustness_cases_learner import cases_learner
from robustness_cases_recorder import cases_recorder
from robustness_cases_sim import cases_demonstrator, cases_sim_robot
from robustness_harness import AREAS, Lab, Result, short

#: The command that writes the table of the doc, as the doc shows it.
COMMAND = "python test/robustness/robustness_table.py"

#: Case groups in table order: (name, function).
GROUPS: list[tuple[str, Callable[[Lab], list[Result]]]] = [
    ("cli-learn", cases_cli_learn),
    ("cli-misc", cases_cli_misc),
    ("cli-ros", cases_cli_ros),
    ("cli-demo", cases_cli_demo),
    ("bags", cases_bags),
    ("recorder", cases_recorder),
    ("learner", cases_learner),
    ("executor", cases_executor),
    ("sim_robot", cases_sim_robot),
    ("demonstrator", cases_demonstrator),
]


def run_groups(lab: Lab, only: Sequence[str] = (), log: Callable[[str], None] | None = None
               ) -> list[Result]:
    """Run the groups named in ``only`` (``cli`` selects every ``cli-*``; all when empty)."""
    results = []
    for name, group in GROUPS:
        if only and not any(name == o or name.startswith(o + "-") for o in only):
            continue
        start = time.monotonic()
        try:
            rows = group(lab)
        except Exception:  # noqa: BLE001 - a harness failure is reported, not hidden
            rows = [Result(f"{name}-harness", "harness", f"group {name}",
                           behaviour="the harness failed: " + short(traceback.format_exc(),
                                                                     300),
                           problems=["harness failure"])]
        results.extend(rows)
        if log is not None:
            bad = sum(not r.ok for r in rows)
            log(f"{name}: {len(rows)} case(s), {bad} with problems, "
                f"{time.monotonic() - start:.0f} s")
    return results


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def markdown(results: Sequence[Result], command: str) -> str:
    """The table and its totals as Markdown."""
    crashes = sum(r.crash for r in results)
    tracebacks = sum(r.traceback for r in results)
    lost = sum(r.lost or 0 for r in results)
    problems = [r for r in results if r.problems]
    by_area = {a: sum(r.area == a for r in results) for a in AREAS}
    lines = [
        f"{len(results)} bad inputs ("
        + ", ".join(f"{n} {a}" for a, n in by_area.items() if n)
        + f"): **{crashes} crashes, {tracebacks} tracebacks, {lost} finished demonstrations "
        f"lost**; {len(problems)} behaviour(s) differ from what a robot owner expects "
        "(column *verdict*).",
        "",
        f"Produced by `{command}`.",
        "",
        "| # case | area | bad input | what the package did | crash | traceback | demos lost "
        "| verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for k, r in enumerate(results, 1):
        verdict = "ok" if not r.problems else "**PROBLEM**: " + "; ".join(r.problems)
        lines.append(
            f"| {k} `{r.case}` | {r.area} | {_cell(r.tried)} | {_cell(r.behaviour)} | "
            f"{'**yes**' if r.crash else 'no'} | {'**yes**' if r.traceback else 'no'} | "
            f"{'-' if r.lost is None else r.lost} | {_cell(verdict)} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the cases and print (or write) the table; exit 1 if any row is not ok."""
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--only", default="", help="comma-separated groups or areas")
    parser.add_argument("--in-process", action="store_true",
                        help="run CLI cases through cli.main instead of subprocesses")
    parser.add_argument("--domain-base", type=int, default=60)
    parser.add_argument("--markdown", default=None,
                        help="write the table into this file between the markers")
    parser.add_argument("--keep", action="store_true", help="keep the scratch directory")
    args = parser.parse_args(argv)
    only = [o for o in args.only.split(",") if o]
    import tempfile

    workdir = Path(tempfile.mkdtemp(prefix="robustness_"))
    try:
        lab = Lab(workdir, args.domain_base, cli_subprocess=not args.in_process)
        results = run_groups(lab, only, log=lambda t: print(t, file=sys.stderr, flush=True))
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    command = COMMAND + (f" --only {args.only}" if only else "") + (
        " --in-process" if args.in_process else "") + (
        f" --markdown {args.markdown}" if args.markdown else "")
    table = markdown(results, command)
    if args.markdown:
        _write_between_markers(Path(args.markdown), table)
    print(table)
    return 0 if all(r.ok for r in results) else 1


BEGIN, END = "<!-- robustness table: begin -->", "<!-- robustness table: end -->"


def _write_between_markers(path: Path, table: str) -> None:
    """Replace the text between the markers of ``path`` (append both if missing)."""
    text = path.read_text() if path.exists() else ""
    block = f"{BEGIN}\n{table}{END}"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        text = head + block + rest.split(END, 1)[1]
    else:
        text = text + ("\n" if text and not text.endswith("\n") else "") + block + "\n"
    path.write_text(text)


if __name__ == "__main__":
    sys.exit(main())
