"""Polling with a deadline, for tests, tools and clients that wait on a running graph.

ROS-free (only ``time``), so the learning core's tests may import it through the shared
``conftest.py`` without importing ROS.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["wait_for"]


def wait_for(predicate: Callable[[], bool], timeout: float = 20.0, step: float = 0.01
             ) -> bool:
    """Poll ``predicate`` until it is true or ``timeout`` seconds pass.

    Parameters
    ----------
    predicate : callable () -> bool
    timeout : float
        Seconds of wall time.
    step : float
        Seconds between polls.

    Returns
    -------
    bool
        True when the predicate held in time, else its value at the deadline.
    """
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return bool(predicate())
        time.sleep(step)
    return True
