"""The paper's experiments and the benchmarks of ``policy-align bench``.

Data sets that run in parallel go through the one process pool of :mod:`.pool`.
"""
