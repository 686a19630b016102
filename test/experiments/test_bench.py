"""``policy-align bench`` wiring and the Table I runner (policy_align_ros.experiments.bench)."""

import json

import numpy as np

from policy_align_ros.cli import main


def test_toy_bench_writes_table_raw_numbers_and_figure(tmp_path, capsys):
    assert main(["bench", "toy", "--datasets", "1", "--jobs", "1", "--out", str(tmp_path)]) == 0
    table = (tmp_path / "toy.md").read_text()
    assert table.count("| ours |") == 9 and table.count("| paper |") == 9
    raw = json.loads((tmp_path / "toy.json").read_text())
    assert set(raw) == {f"{p}_K{k}_{r}" for p, k in [("parabola", 40), ("sinusoid", 40),
                                                      ("sinusoid", 100)]
                        for r in ("narrow", "medium", "wide")}
    assert all(np.isfinite(v[0]["nupe"]) for v in raw.values())
    assert (tmp_path / "toy.png").stat().st_size > 10_000
    assert table.strip() in capsys.readouterr().out  # prints the table it writes


def test_bad_bench_arguments_exit_2_and_write_nothing(tmp_path):
    assert main(["bench", "toy", "--jobs", "0", "--out", str(tmp_path)]) == 2
    assert main(["bench", "toy", "--datasets", "0", "--out", str(tmp_path)]) == 2
    assert list(tmp_path.iterdir()) == []
