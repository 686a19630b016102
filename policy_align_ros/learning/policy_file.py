"""PolicyAlign's model file: the header and the arrays :meth:`PolicyAlign.save
<policy_align_ros.learning.policy_align.PolicyAlign.save>` writes and
:meth:`~policy_align_ros.learning.policy_align.PolicyAlign.load` reads back, through
:mod:`policy_align_ros.learning.model_io` (``docs/design.md`` section 4).

The regressor is named by its class (:func:`~policy_align_ros.learning.regressors.registry.
regressor_class`) and stored with its own ``get_state``: its arrays under
``regressor.<name>``, its header under ``regressor.meta``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from policy_align_ros.learning import model_io
from policy_align_ros.learning.base import check_is_fitted
from policy_align_ros.learning.regressors.registry import regressor_class

__all__ = ["model_robot_fields", "read_model", "read_robot_fields", "write_model"]


def write_model(model, path: str | Path) -> Path:
    """Write the fitted PolicyAlign ``model`` atomically to ``path`` (see
    :meth:`PolicyAlign.save <policy_align_ros.learning.policy_align.PolicyAlign.save>`)."""
    check_is_fitted(model, "regressor_")
    regressor, reg_arrays = _regressor_state(model.regressor_, "regressor")
    folds = [_regressor_state(r, f"fold{i}")
             for i, r in enumerate(getattr(model, "fold_regressors_", []))]
    params = {k: v for k, v in model.get_params(deep=False).items() if k != "regressor"}
    if isinstance(params["random_state"], np.random.Generator):
        params["random_state"] = None  # a file cannot hold its state
    definition = getattr(model, "state_definition_", None)
    if definition is not None and not isinstance(definition, dict):
        raise ValueError("state_definition_ must be None or a JSON-able dict, got "
                         f"{type(definition).__name__}")
    state = ("frame positions" if definition is not None
             else "joint positions" if model.joint_names_ else "positions")
    robot = getattr(model, "robot_", None)
    if robot is not None and not isinstance(robot, str):
        raise ValueError(f"robot_ must be None or a str, got {type(robot).__name__}")
    header = {
        "kind": "policy_align",
        "robot": robot,
        "joint_names": model.joint_names_,
        "state": state,
        "state_definition": definition,
        "policy_units": "per second" if model.timed_ else "per step",
        "n_features": model.n_features_in_,
        "sigma2": model.sigma2_,
        "params": params,
        "regressor": regressor,
        "folds": [entry for entry, _ in folds],
        "training": model.fit_summary_,
        "support_spacing": model.support_spacing_,
        # Exact (fit_summary_ holds its square root) and the Euler rule's factor.
        "position_noise": model.position_noise_,
        "euler_scale": model.euler_scale_,
    }
    lengths = np.array([len(p) for p in model.aligned_potentials_])
    arrays = {
        "offsets": model.offsets_,
        "groups": model.groups_,
        "inliers": model.inliers_,
        "aligned_lengths": lengths,
        "aligned_potentials": np.concatenate(model.aligned_potentials_),
        "support_states": model.support_states_,
        **reg_arrays,
        **{k: v for _, arrays_i in folds for k, v in arrays_i.items()},
    }
    return model_io.save_npz(path, header, arrays)


def read_model(cls: type, path: str | Path):
    """A fitted ``cls`` (PolicyAlign) read from ``path`` (see
    :meth:`PolicyAlign.load <policy_align_ros.learning.policy_align.PolicyAlign.load>`)."""
    header, arrays = model_io.load_npz(path, kind="policy_align")
    try:
        params = dict(_field(header, "params", dict))
        model = cls(**params)
        _read_header(model, header, arrays, params)
        _read_arrays(model, header, arrays)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise ValueError(f"{path}: malformed policy_align model file ({err})") from None
    return model


def read_robot_fields(path: str | Path) -> tuple[str | None, list[str] | None]:
    """The robot and joints a model file was learnt for, from its header only.

    Returns
    -------
    (robot, joints)
        ``robot``: the header's ``robot`` (example-robot-data name or URDF path), else
        that of its frames state definition, else None (files written before the field,
        or learnt without naming the robot); ``joints``: the joint positions it was
        learnt on (a frames state: its definition's joints), else None.

    Raises
    ------
    ValueError, FileNotFoundError
        For a file that is no policy_align model file.
    """
    return _robot_fields(model_io.load_header(path, kind="policy_align"))


def model_robot_fields(model) -> tuple[str | None, list[str] | None]:
    """:func:`read_robot_fields` of a model already read (:func:`read_model`): its
    ``robot_``, ``state_definition_`` and ``joint_names_`` are its file's header fields."""
    return _robot_fields({"robot": model.robot_, "state_definition": model.state_definition_,
                          "joint_names": model.joint_names_})


def _robot_fields(header: dict) -> tuple[str | None, list[str] | None]:
    """``(robot, joints)`` of a model file's header (see :func:`read_robot_fields`)."""
    definition = header.get("state_definition")
    definition = definition if isinstance(definition, dict) else {}
    robot = header.get("robot") or definition.get("robot")
    joints = definition.get("joints") if definition else header.get("joint_names")
    if not isinstance(robot, str):
        robot = None
    if not (isinstance(joints, list) and joints and all(isinstance(j, str) for j in joints)):
        joints = None
    return robot, joints


def _read_header(model, header: dict, arrays: dict[str, np.ndarray], params: dict) -> None:
    """The header's attributes of ``model``, and its regressor (KeyError, TypeError or
    ValueError when malformed)."""
    regressor = _field(header, "regressor", dict)
    model.regressor_ = _regressor(regressor, arrays, "regressor")
    # Files written before the fold models were kept have none.
    folds = header.get("folds", [])
    if not isinstance(folds, list):
        raise ValueError(f"folds must be a JSON array, got {type(folds).__name__}")
    model.fold_regressors_ = [
        _regressor(_field({f"folds[{i}]": f}, f"folds[{i}]", dict), arrays, f"fold{i}")
        for i, f in enumerate(folds)]
    model.sigma2_ = float(header["sigma2"])
    n = _field(header, "n_features", int)
    if n < 1:
        raise ValueError(f"n_features must be positive, got {n}")
    model.n_features_in_ = n
    for name, reg in [("the regressor", model.regressor_)] + [
            (f"fold model {i}", r) for i, r in enumerate(model.fold_regressors_)]:
        reg_n = getattr(reg, "n_features_in_", n)
        if reg_n != n:
            raise ValueError(f"{name} takes {reg_n} features, n_features is {n}")
    model.joint_names_ = header["joint_names"]
    if model.joint_names_ is not None and (
            not isinstance(model.joint_names_, list) or len(model.joint_names_) != n):
        raise ValueError(f"joint_names must be null or a list of {n} names")
    # Files written before the robot field know no robot.
    model.robot_ = header.get("robot")
    if model.robot_ is not None and not isinstance(model.robot_, str):
        raise ValueError("robot must be null or a string")
    # Files written before task-space states have no definition: joint states.
    model.state_definition_ = header.get("state_definition")
    if model.state_definition_ is not None and not isinstance(
            model.state_definition_, dict):
        raise ValueError("state_definition is not a dict")
    model.timed_ = header["policy_units"] == "per second"
    model.fit_summary_ = _field(header, "training", dict)
    # Files written before "auto" existed used the rule they name.
    model.integration_ = model.fit_summary_.get("integration", params.get(
        "integration", "euler"))
    # Files written before the lag was estimated used none.
    model.tracking_lag_ = float(model.fit_summary_.get("tracking_lag", 0.0))
    model.euler_scale_, model.position_noise_ = _noise_and_scale(
        header, model.fit_summary_)


def _read_arrays(model, header: dict, arrays: dict[str, np.ndarray]) -> None:
    """The learnt arrays of ``model``, checked against its header's counts."""
    n = model.n_features_in_
    model.offsets_ = _array(arrays, "offsets", "f", 1)
    K = len(model.offsets_)
    expected = model.fit_summary_.get("n_trajectories", K)
    if expected != K:
        raise ValueError(f"{K} offsets for n_trajectories = {expected!r}")
    # Files written before per-demonstration time units shared one clock.
    scales = model.fit_summary_.get("timing_scales", [1.0] * K)
    model.timing_scales_ = np.asarray(scales, dtype=float).reshape(-1)
    if len(model.timing_scales_) != K or not np.all(model.timing_scales_ > 0):
        raise ValueError(f"timing_scales must hold {K} positive numbers")
    model.groups_ = _array(arrays, "groups", "iu", 1, K)
    model.inliers_ = _array(arrays, "inliers", "iu", 1)
    if np.any(model.inliers_ < 0) or np.any(model.inliers_ >= K):
        raise ValueError(f"inliers must index the {K} trajectories")
    lengths = _array(arrays, "aligned_lengths", "iu", 1, K)
    potentials = _array(arrays, "aligned_potentials", "f", 1)
    if np.any(lengths < 0) or int(lengths.sum()) != len(potentials):
        raise ValueError(f"aligned_lengths sum to {int(lengths.sum())}, "
                         f"aligned_potentials holds {len(potentials)} values")
    model.aligned_potentials_ = np.split(potentials, np.cumsum(lengths)[:-1])
    model.support_states_ = np.asarray(_array(arrays, "support_states", "fiu", 2),
                                       dtype=float)
    if model.support_states_.shape[1] != n:
        raise ValueError(f"support_states has {model.support_states_.shape[1]} "
                         f"columns, n_features is {n}")
    model.support_spacing_ = float(header["support_spacing"])
    model._support_tree = None


def _regressor_state(regressor, prefix: str) -> tuple[dict, dict[str, np.ndarray]]:
    """A regressor's header entry (``class`` and ``meta``) and its arrays named
    ``<prefix>.<name>``, as :func:`_regressor` reads them back."""
    arrays, meta = regressor.get_state()
    return ({"class": type(regressor).__name__, "meta": meta},
            {f"{prefix}.{k}": v for k, v in arrays.items()})


def _regressor(entry: dict, arrays: dict[str, np.ndarray], prefix: str):
    """The regressor a header ``entry`` (``class`` and ``meta``) names, from its arrays
    ``<prefix>.<name>``."""
    own = {k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith(prefix + ".")}
    reg_class = regressor_class(_field(entry, "class", str))
    return reg_class.from_state(own, _field(entry, "meta", dict))


def _field(mapping: dict, key: str, kind: type) -> Any:
    """``mapping[key]``, which must be a ``kind`` (an int is not a bool); ValueError (or
    KeyError when missing) naming the key otherwise."""
    value = mapping[key]
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ValueError(f"{key} must be a JSON {_JSON_NAMES.get(kind, kind.__name__)}, "
                         f"got {type(value).__name__}")
    return value


_JSON_NAMES = {dict: "object", list: "array", str: "string", int: "integer"}


def _array(arrays: dict[str, np.ndarray], name: str, kinds: str, ndim: int,
           length: int | None = None) -> np.ndarray:
    """The model file's array ``name``, checked for its dtype kinds (``"f"``, ``"iu"``),
    number of dimensions and (first) length; ValueError naming it otherwise."""
    value = arrays[name]
    if value.dtype.kind not in kinds or value.ndim != ndim:
        raise ValueError(f"array {name!r} must be {ndim}-D of kind {kinds!r}, got "
                         f"{value.dtype} of shape {value.shape}")
    if length is not None and len(value) != length:
        raise ValueError(f"array {name!r} has {len(value)} entries for {length} "
                         "trajectories")
    return value


def _noise_and_scale(header: dict, summary: dict) -> tuple[float, float]:
    """``euler_scale_`` and ``position_noise_`` of a model file: the header's exact values,
    else the training summary's (``position_noise_rms`` squared), else 1 and 0 (files
    written before either existed)."""
    scale = float(header.get("euler_scale", summary.get("euler_scale", 1.0)))
    if "position_noise" in header:
        noise = float(header["position_noise"])
    else:
        noise = float(summary.get("position_noise_rms", 0.0)) ** 2
    if not (math.isfinite(scale) and math.isfinite(noise)):
        raise ValueError(f"euler_scale ({scale!r}) and position_noise ({noise!r}) must be "
                         "finite")
    return scale, noise
