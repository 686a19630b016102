"""Robustness cases of the command line: ``policy-align learn``, ``bench``, ``call``,
``param`` and ``demo`` with arguments they cannot use."""

from __future__ import annotations

import shutil

from robustness_harness import Lab, Result, Run
from robustness_rigs import NodeRig


def cli_result(case: str, tried: str, run: Run, code: int | None, *needles: str,
                area: str = "cli") -> Result:
    r = Result(case, area, tried, crash=run.crashed, traceback=run.traceback)
    r.behaviour = f"exit {run.code}: {run.line()}" if run.code is not None else \
        "did not finish within the timeout (killed)"
    r.data.update(code=run.code, out=run.out, err=run.err)
    if code is not None:
        r.expect(run.code == code, f"exit status {run.code}, expected {code}")
    text = run.out + run.err
    for needle in needles:
        r.expect(needle in text, f"the message does not mention {needle!r}")
    return r


def cases_cli_learn(lab: Lab) -> list[Result]:
    """``policy-align learn`` with unusable paths and options."""
    out = []
    work = lab.path("cli_learn")
    good = lab.good_dataset()
    model = str(work / "model.npz")
    (work / "empty").mkdir()
    (work / "notes.txt").write_text("not a bag\n")
    (work / "a_file").write_text("x")
    (work / "a_dir").mkdir()

    def learn(case, tried, argv, code, *needles):
        out.append(cli_result(case, tried, lab.cli("learn", *argv), code, *needles))
        return out[-1]

    learn("learn-missing-path", "`learn /nonexistent/demos --out m.npz`",
          [str(work / "nonexistent" / "demos"), "--out", model], 2, "nonexistent")
    learn("learn-empty-dir", "`learn EMPTY_DIR --out m.npz`",
          [str(work / "empty"), "--out", model], 2, "empty")
    learn("learn-not-a-bag", "`learn notes.txt --out m.npz` (a text file)",
          [str(work / "notes.txt"), "--out", model], 2, "notes.txt")
    learn("learn-sigma-negative", "`learn GOOD --sigma -1`",
          [str(good), "--out", model, "--sigma", "-1"], 2, "sigma")
    learn("learn-sigma-nan", "`learn GOOD --sigma nan`",
          [str(good), "--out", model, "--sigma", "nan"], 2, "sigma")
    learn("learn-sigma-word", "`learn GOOD --sigma huge`",
          [str(good), "--out", model, "--sigma", "huge"], 2, "sigma")
    learn("learn-joints-empty-name", "`learn GOOD --joints j1,,j2`",
          [str(good), "--out", model, "--joints", "j1,,j2"], 2, "joints")
    learn("learn-joints-repeated", "`learn GOOD --joints j1,j1`",
          [str(good), "--out", model, "--joints", "j1,j1"], 2, "j1")
    learn("learn-joints-unknown", "`learn GOOD --joints j1,not_a_joint` (bags have j1, j2)",
          [str(good), "--out", model, "--joints", "j1,not_a_joint"], 2, "not_a_joint", "j2")
    learn("learn-gap-nan", "`learn GOOD --gap nan`",
          [str(good), "--out", model, "--gap", "nan"], 2, "gap")
    learn("learn-out-under-file", "`learn GOOD --out A_FILE/model.npz` (parent is a file)",
          [str(good), "--out", str(work / "a_file" / "model.npz")], 2, "a_file")
    learn("learn-out-is-dir", "`learn GOOD --out A_DIR` (an existing directory)",
          [str(good), "--out", str(work / "a_dir")], 2, "a_dir")
    learn("learn-state-unknown-kind", "`learn GOOD --state velocities`",
          [str(good), "--out", model, "--state", "velocities"], 2, "state")
    learn("learn-state-empty-frames", "`learn GOOD --state frames:`",
          [str(good), "--out", model, "--state", "frames:"], 2, "frame")
    learn("learn-state-frames-no-robot", "`learn GOOD --state frames:arm_left_7_link` "
          "(no `--robot`)", [str(good), "--out", model, "--state", "frames:arm_left_7_link"],
          2, "robot")
    learn("learn-state-unknown-frame", "`learn GOOD --robot talos --state frames:no_frame`",
          [str(good), "--out", model, "--robot", "talos", "--state", "frames:no_frame"], 2)
    one = lab.dataset_with("one_demo", n_good=1)
    learn("learn-one-demo", "`learn ONE_BAG_DATASET` (a single demonstration)",
          [str(one), "--out", model], 2, "2")
    r = learn("learn-same-dataset-twice", "`learn GOOD GOOD` (every bag given twice)",
              [str(good), str(good), "--out", str(work / "twice.npz")], None)
    r.expect(r.data["code"] in (0, 2), "exit status neither 0 nor 2")
    # A bag named twice is reported by its name marked as the repeat.
    r.expect("(repeat)" in r.data["out"] + r.data["err"], "the duplicates are not reported")
    dup = lab.dataset_with("dup_bags")
    bags = sorted(dup.iterdir())
    for bag in bags:
        shutil.copytree(bag, dup / f"copy_of_{bag.name}")
    r = learn("learn-duplicated-bags", "`learn DATASET` where every bag has a copy",
              [str(dup), "--out", str(work / "dup.npz")], None)
    r.expect(r.data["code"] in (0, 2), "exit status neither 0 nor 2")
    r.expect(all(f"copy_of_{bag.name}" in r.data["out"] + r.data["err"] for bag in bags),
             "the duplicates are not reported")
    return out


def cases_cli_misc(lab: Lab) -> list[Result]:
    """``bench`` and the command itself with bad arguments."""
    out = []
    work = lab.path("cli_bench")
    out.append(cli_result("no-command", "`policy-align` (no sub-command)", lab.cli(), 2))
    out.append(cli_result("bench-unknown", "`bench nosuch`", lab.cli("bench", "nosuch"), 2,
                           "invalid choice"))
    out.append(cli_result(
        "bench-jobs-zero", "`bench toy --jobs 0 --datasets 1`",
        lab.cli("bench", "toy", "--jobs", "0", "--datasets", "1", "--out", str(work / "a"),
                timeout=300), 2, "jobs"))
    out.append(cli_result(
        "bench-datasets-negative", "`bench toy --datasets -1`",
        lab.cli("bench", "toy", "--datasets", "-1", "--out", str(work / "b"), timeout=300),
        2, "datasets"))
    out.append(cli_result(
        "bench-set-malformed", "`bench suite --set offset_ridge` (no `=`)",
        lab.cli("bench", "suite", "--set", "offset_ridge", "--datasets", "1",
                "--out", str(work / "c"), timeout=300), 2, "offset_ridge"))
    return out


def cases_cli_ros(lab: Lab) -> list[Result]:
    """``call`` and ``param`` against a running recorder, and against nothing."""
    from policy_align_ros.nodes.recorder import RecorderNode

    out = []
    work = lab.path("cli_ros")
    rig = NodeRig(lab, RecorderNode, {"dataset_dir": str(work / "demos")})
    d = rig.domain
    try:
        out.append(cli_result("call-missing-service", "`call /no_such_service --timeout 2`",
                               lab.cli("call", "/no_such_service", "--timeout", "2",
                                       domain=d), 3, "not available"))
        out.append(cli_result(
            "call-wrong-type", "`call /recorder/start_demo --data true` (a Trigger)",
            lab.cli("call", "/recorder/start_demo", "--data", "true", domain=d), 2,
            "omit --data"))
        out.append(cli_result(
            "call-unsupported-type", "`call /recorder/get_parameters` (not Trigger/SetBool)",
            lab.cli("call", "/recorder/get_parameters", "--timeout", "10", domain=d), 2,
            "GetParameters"))
        out.append(cli_result("call-timeout-zero", "`call /recorder/stop_demo --timeout 0`",
                               lab.cli("call", "/recorder/stop_demo", "--timeout", "0",
                                       domain=d), 2, "timeout"))
        out.append(cli_result(
            "param-missing-node", "`param get /no_such_node rate_hz --timeout 2`",
            lab.cli("param", "get", "/no_such_node", "rate_hz", "--timeout", "2", domain=d),
            3, "no_such_node"))
        out.append(cli_result("param-unknown-name", "`param get /recorder no_such_param`",
                               lab.cli("param", "get", "/recorder", "no_such_param",
                                       domain=d), 2, "no_such_param"))
        out.append(cli_result(
            "param-bad-value-type", "`param set /recorder auto_split_gap_s fast`",
            lab.cli("param", "set", "/recorder", "auto_split_gap_s", "fast", domain=d), 2,
            "double"))
        out.append(cli_result(
            "param-refused-value", "`param set /recorder auto_split_gap_s -1`",
            lab.cli("param", "set", "/recorder", "auto_split_gap_s", "-1", domain=d), 1,
            "refused"))
        out.append(cli_result(
            "param-read-only", "`param set /recorder qos_depth 5` (read-only)",
            lab.cli("param", "set", "/recorder", "qos_depth", "5", domain=d), 1, "read-only"))
        out.append(cli_result(
            "call-invalid-name", "`call '/no such service'` (not a valid name)",
            lab.cli("call", "/no such service", "--timeout", "2", domain=d), 2, "valid"))
        out.append(cli_result(
            "param-invalid-node-name", "`param get 'no such node' rate_hz` (not a valid name)",
            lab.cli("param", "get", "no such node", "rate_hz", "--timeout", "2", domain=d),
            2, "not a valid node name"))
        out.append(cli_result(
            "param-array-bad-yaml", "`param set /recorder joints '[j1, j2'` (unclosed YAML)",
            lab.cli("param", "set", "/recorder", "joints", "[j1, j2", domain=d), 2, "YAML"))
        out.append(cli_result(
            "param-unset-parameter", "`param set /recorder joints '[j1, j1]'` (declared, "
            "unset, repeated joint)",
            lab.cli("param", "set", "/recorder", "joints", "[j1, j1]", domain=d), 1,
            "listed twice"))
        out.append(cli_result("param-set-no-value", "`param set /recorder dataset_dir`",
                               lab.cli("param", "set", "/recorder", "dataset_dir", domain=d),
                               2, "VALUE"))
        r = out[-1]
        r.expect(rig.alive() and not rig.errors, "the recorder did not survive the calls")
    finally:
        rig.close()
    return out


def cases_cli_demo(lab: Lab) -> list[Result]:
    """``policy-align demo`` with arguments it cannot use (it must stop before the graph)."""
    work = lab.path("cli_demo")
    (work / "a_file").write_text("x")
    d = lab.domain()
    return [
        cli_result("demo-unknown-robot", "`demo --robot no_such_robot`",
                    lab.cli("demo", "--robot", "no_such_robot", "--out", str(work / "a"),
                            domain=d, timeout=300), 2, "no_such_robot"),
        cli_result("demo-out-under-file", "`demo --out A_FILE/out` (parent is a file)",
                    lab.cli("demo", "--out", str(work / "a_file" / "out"), domain=d,
                            timeout=300), 2, "a_file"),
        cli_result("demo-seed-negative", "`demo --seed -1`",
                    lab.cli("demo", "--seed", "-1", "--out", str(work / "b"), domain=d,
                            timeout=300), 2, "seed"),
    ]


