"""Robustness cases of the learner: bad parameters, learning without data, learning while
learning (a 60-demonstration fit, so the table runs them and the tests leave them out)."""

from __future__ import annotations

from robustness_harness import Lab, Result, short, write_good_dataset
from robustness_rigs import (
    NodeRig,
    node_start,
    param_case,
    rig_case,
    service_case,
    start_refused,
    trigger,
)

from policy_align_ros.polling import wait_for


def cases_learner(lab: Lab) -> list[Result]:
    """learner: bad parameters, learning without data, learning while learning."""
    from std_srvs.srv import Trigger

    from policy_align_ros.nodes.learner import Learner

    out: list[Result] = []
    work = lab.path("learner")
    big = work / "big"
    write_good_dataset(big, 60, seed=3)  # a fit that takes long enough to overlap
    (work / "empty").mkdir()
    rig = NodeRig(lab, Learner, {"dataset_dir": str(big), "model_path": str(work / "m.npz")})
    try:
        p = param_case
        out.append(p(rig, "learner-sigma-word", "learner `sigma: huge`", "sigma", "huge",
                     "sigma"))
        out.append(p(rig, "learner-sigma-negative", "learner `sigma: '-1'`", "sigma", "-1",
                     "sigma"))
        out.append(p(rig, "learner-sigma-nan", "learner `sigma: nan`", "sigma", "nan",
                     "sigma"))
        out.append(p(rig, "learner-holdout-out-of-range", "learner `holdout_fraction: 1.5`",
                     "holdout_fraction", 1.5))
        out.append(p(rig, "learner-dataset-dir-empty", "learner `dataset_dir: ''`",
                     "dataset_dir", "", "dataset_dir"))
        out.append(p(rig, "learner-joints-repeated", "learner `joints: [j1, j1]`",
                     "joints", ["j1", "j1"], "joints"))
        out.append(p(rig, "learner-gap-negative", "learner `gap_s: -1.0`", "gap_s", -1.0))
        out.append(p(rig, "learner-seed-wrong-type", "learner `seed: 'abc'` (string)",
                     "seed", "abc"))

        r = Result("learner-learn-while-learning", "services",
                   "learner `~/learn` twice at once (60 demonstrations)")
        with rig_case(r, rig):
            client = rig.client(Trigger, "/learner/learn")
            client.wait_for_service(timeout_sec=10.0)
            first = client.call_async(Trigger.Request())
            second = client.call_async(Trigger.Request())
            wait_for(lambda: first.done() and second.done(), 300.0)
        answers = [f.result() for f in (first, second) if f.done()]
        refused = [a for a in answers if not a.success]
        r.data["answers"] = [(a.success, a.message) for a in answers]
        r.behaviour = "; ".join(
            f"success={str(a.success).lower()}: {short(a.message, 90)}" for a in answers)
        r.expect(len(answers) == 2, "a call was not answered")
        r.expect(len(refused) == 1 and len(answers) - len(refused) == 1,
                 "not exactly one call refused as already running")
        out.append(r)

        s = service_case
        learn = lambda: trigger(rig, "/learner/learn")  # noqa: E731
        rig.set_param("dataset_dir", str(work / "empty"))
        out.append(s(rig, "learner-learn-empty-dataset",
                     "learner `~/learn` with an empty `dataset_dir`", learn, False, "empty"))
        rig.set_param("dataset_dir", str(work / "missing"))
        out.append(s(rig, "learner-learn-missing-dataset",
                     "learner `~/learn` with a `dataset_dir` that does not exist", learn,
                     False, "missing"))
        one = lab.dataset_with("learner_one", n_good=1)
        rig.set_param("dataset_dir", str(one))
        out.append(s(rig, "learner-learn-one-demo",
                     "learner `~/learn` with a single demonstration", learn, False, "2"))
        (work / "a_file").write_text("x")
        rig.set_param("dataset_dir", str(lab.good_dataset()))
        rig.set_param("model_path", str(work / "a_file" / "m.npz"))
        out.append(s(rig, "learner-learn-model-under-file",
                     "learner `~/learn` with `model_path` under a file", learn, False,
                     "a_file"))
    finally:
        rig.close()
    r = Result("learner-start-bad-sigma", "parameters",
               "`learner --ros-args -p sigma:=huge` (start-up)")
    start_refused(r, node_start(lab, "learner", "-p", "sigma:=huge"), "sigma")
    out.append(r)
    return out


