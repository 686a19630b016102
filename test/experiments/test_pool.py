"""The experiments' one process pool (policy_align_ros.experiments.pool)."""

import math
import os

from policy_align_ros.experiments.pool import BLAS_THREAD_VARIABLES, parallel_map


def test_parallel_map_keeps_the_task_order_in_and_out_of_process(capsys):
    tasks = [4.0, 1.0, 9.0, 16.0]
    assert parallel_map(math.sqrt, tasks, jobs=1) == [2.0, 1.0, 3.0, 4.0]
    saved = {k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES}
    assert parallel_map(math.sqrt, tasks, jobs=2, label="sqrt") == [2.0, 1.0, 3.0, 4.0]
    assert {k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES} == saved
    assert capsys.readouterr().out == ""  # progress goes to stderr only
