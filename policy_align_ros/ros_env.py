"""The ROS environment, checked before ``rclpy.init`` (ROS-free).

Nodes (:func:`~policy_align_ros.nodes._common.run_node`), the short-lived clients
(``policy-align call`` and ``param``) and ``policy-align demo`` read ``ROS_DOMAIN_ID`` the
same way: an id Fast DDS cannot use with its default ports is refused with a message that
names the variable and the fix, instead of Fast DDS's one line about a port number.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

__all__ = ["DOMAIN_RANGE", "FASTDDS_PROFILES", "domain_id_problem", "fastdds_profiled"]

#: The ROS domain ids Fast DDS accepts with its default ports (``docs/design.md``
#: section 8); beyond them it prints only that a port number is too high, and exits.
DOMAIN_RANGE = (0, 232)
#: Environment variables that give Fast DDS a profile, whose ports may allow other ids.
FASTDDS_PROFILES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def fastdds_profiled(environ: Mapping[str, str]) -> bool:
    """Whether ``environ`` gives Fast DDS a profile (:data:`FASTDDS_PROFILES`), whose ports
    may allow domain ids beyond :data:`DOMAIN_RANGE`."""
    return any(environ.get(name) for name in FASTDDS_PROFILES)


def domain_id_problem(environ: Mapping[str, str] | None = None) -> str:
    """Why ``ROS_DOMAIN_ID`` in ``environ`` (default ``os.environ``) cannot work, naming the
    fix; "" when it can, is unset, or is left to a Fast DDS profile or to rcl (a value that
    is no integer, which rcl names itself)."""
    environ = os.environ if environ is None else environ
    value = environ.get("ROS_DOMAIN_ID", "").strip()
    if not value or fastdds_profiled(environ):
        return ""
    try:
        domain = int(value)
    except ValueError:
        return ""
    low, high = DOMAIN_RANGE
    if low <= domain <= high:
        return ""
    return (f"ROS_DOMAIN_ID={domain} is outside {low}-{high}, the domain ids Fast DDS "
            f"accepts with its default ports: choose one in {low}-{high} (or give Fast DDS "
            f"a profile with other ports: {FASTDDS_PROFILES[0]})")
