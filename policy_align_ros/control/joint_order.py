"""Joint orders: the model's against the controller's, the controller's against the
executor's."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["NO_ORDER_CHECK", "controller_order_refusal", "joint_order_problem",
           "model_permutation", "order_check_off", "unchecked_order_refusal"]


def model_permutation(model_joints: Sequence[str] | None, joints: Sequence[str]) -> np.ndarray:
    """Indices ``p`` such that ``q[p]`` is ``q`` (ordered as ``joints``) in model order.

    Parameters
    ----------
    model_joints : sequence of str or None
        The joint names the model was trained on (None: trust the order of ``joints``).
    joints : sequence of str
        The controller's joint order.

    Returns
    -------
    ndarray of int, shape (n,)

    Raises
    ------
    ValueError
        If the two sets of names differ; the message lists the missing and extra names.
    """
    joints = list(joints)
    if model_joints is None:
        return np.arange(len(joints))
    model_joints = list(model_joints)
    missing = [j for j in model_joints if j not in joints]
    extra = [j for j in joints if j not in model_joints]
    if missing or extra or len(model_joints) != len(joints):
        raise ValueError(
            "model joints do not match the configured joints: "
            f"model needs {missing or 'nothing more'}, configured but not in the model "
            f"{extra or 'none'}"
        )
    index = {name: i for i, name in enumerate(joints)}
    return np.array([index[name] for name in model_joints], dtype=int)


def joint_order_problem(controller_joints: Sequence[str], joints: Sequence[str],
                        controller: str) -> str:
    """What differs between a controller's ``joints`` and the executor's command order.

    Parameters
    ----------
    controller_joints : sequence of str
        The controller's ``joints`` parameter (the order it reads the command array in).
    joints : sequence of str
        The executor's ``joints`` (the order it writes the command array in).
    controller : str
        Controller node name, for the message.

    Returns
    -------
    str
        Empty when both lists are equal, else a sentence naming the difference (only the
        parts that differ) and the fix: the executor's ``joints`` in the controller's
        order, or the robot config's.
    """
    theirs, mine = list(controller_joints), list(joints)
    if theirs == mine:
        return ""
    fix = (f"restart the executor with -p joints:=[{','.join(theirs)}] (the controller's "
           f"order) or fix joints in the robot config (robot_config)")
    missing = [j for j in mine if j not in theirs]
    extra = [j for j in theirs if j not in mine]
    if missing or extra or len(theirs) != len(mine):
        parts = [f"{label} {names}" for label, names in (
            ("not in the controller", missing), ("only in the controller", extra)) if names]
        if not parts:  # the same names, one of them listed twice
            parts = [f"{len(theirs)} joints there, {len(mine)} here"]
        return (f"controller {controller} has other joints than the executor: "
                f"{', '.join(parts)}; {fix}, or set controller to the node that takes "
                f"these joints' commands")
    slot = next(i for i, (a, b) in enumerate(zip(theirs, mine, strict=True)) if a != b)
    return (f"controller {controller} orders the joints differently: command slot {slot} "
            f"is {theirs[slot]!r} there and {mine[slot]!r} here (controller order "
            f"{theirs}); {fix}")


#: The ``controller`` value that turns the joint order check off, typed on the command line
#: (``-p controller:=none``; ``-p controller:=`` gives no string at all).
NO_ORDER_CHECK = "none"


def order_check_off(controller: str) -> bool:
    """Whether ``controller`` (the executor's parameter) opts out of the order check.

    Only an explicit choice does: :data:`NO_ORDER_CHECK` (any case, surrounding blanks
    ignored) or an empty string (reachable from a parameter file).
    """
    text = controller.strip()
    return not text or text.lower() == NO_ORDER_CHECK


def unchecked_order_refusal(controller: str, why: str) -> str:
    """The ~/enable refusal when ``controller``'s joint order could not be read.

    Parameters
    ----------
    controller : str
        Controller node name whose ``joints`` parameter was asked for.
    why : str
        What went wrong (no answer within the timeout, no string-array ``joints``).

    Returns
    -------
    str
        A sentence naming the problem and the fixes.
    """
    return (f"joint order of the command array not checked: {why}; start {controller}, "
            f"or set controller to the node whose joints parameter lists the command "
            f"order (-p controller:=/my_controller), or opt out of the check with "
            f"-p controller:={NO_ORDER_CHECK}")


def controller_order_refusal(controller: str, controller_joints: Sequence[str] | None,
                             joints: Sequence[str], answered: bool, timeout_s: float) -> str:
    """The ~/enable refusal after ``controller`` was asked for its ``joints`` parameter.

    Parameters
    ----------
    controller : str
        Controller node name that was asked.
    controller_joints : sequence of str or None
        Its ``joints`` (command order); None when it did not answer or has no
        string-array ``joints``.
    joints : sequence of str
        The executor's joints, in command order.
    answered : bool
        Whether an answer came within ``timeout_s`` (s).

    Returns
    -------
    str
        :func:`joint_order_problem`, or :func:`unchecked_order_refusal` saying why the
        order was not read; empty when the orders match (go ahead).
    """
    if controller_joints is None:
        why = (f"{controller} has no string-array joints parameter" if answered
               else f"{controller} did not answer within {timeout_s:g} s")
        return unchecked_order_refusal(controller, why)
    return joint_order_problem(controller_joints, joints, controller)
