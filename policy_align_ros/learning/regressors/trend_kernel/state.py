"""The numeric arrays and JSON-able header that rebuild a fitted
:class:`~.model.TrendKernelRegression` exactly, and the model rebuilt from them: what a
model file holds of the regressor (``docs/design.md``, section 4)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from policy_align_ros.learning.base import check_is_fitted
from policy_align_ros.learning.model_io import json_float, to_json
from policy_align_ros.learning.regressors.trend_kernel import single_index
from policy_align_ros.learning.regressors.trend_kernel.features import (
    _n_index_weights,
    _n_trend,
)

if TYPE_CHECKING:  # the model imports this module
    from policy_align_ros.learning.regressors.trend_kernel.model import TrendKernelRegression

__all__ = ["STATE_VERSION", "TREND_FORMS", "model_from_state", "model_state"]

#: The header's format version; older versions load (:func:`model_from_state`).
STATE_VERSION = 3
#: Hyperparameters that may be ``inf`` (written as strings).
_HYPER = ("trend_ridge", "length_scale", "kernel_ridge", "offset_ridge")
#: The trend forms: the quadratic, and the single-index trend of :mod:`.single_index` (a
#: profile of one quadratic form; no residual on top). The CV chooses from them.
TREND_FORMS = ("quadratic", "single_index")


def model_state(model: TrendKernelRegression) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Numeric arrays and a JSON-able header that rebuild this model exactly.

    The header's ``params`` are the constructor arguments in plain Python types: NumPy
    scalars (``n_centres=np.int64(300)``) as ints and floats, a Generator
    ``random_state`` as ``None`` (``get_params`` keeps the values as given). Anything
    else JSON cannot hold raises a ValueError naming the parameter.
    """
    check_is_fitted(model, "trend_")
    params = model.get_params(deep=False)
    if isinstance(params["random_state"], np.random.Generator):
        params["random_state"] = None
    for name in _HYPER:
        if params[name] != "cv":
            params[name] = json_float(float(params[name]), "string")
    params = to_json(params, "TrendKernelRegression params")
    meta = {
        "version": STATE_VERSION,
        "params": params,
        "trend_form": model.trend_form_,
        "index_scale": model.index_scale_,
        "trend_ridge": json_float(model.trend_ridge_, "string"),
        "length_scale": float(model.length_scale_),
        "kernel_ridge": json_float(model.kernel_ridge_, "string"),
        "offset_ridge": json_float(model.offset_ridge_, "string"),
        "scale": model.scale_,
        "y_mean": model.y_mean_,
        "y_scale": model.y_scale_,
        "n_features_in": int(model.n_features_in_),
        "goal": None if model.goal_ is None else [float(v) for v in model.goal_],
        "min_curvature": getattr(model, "min_curvature_", None),
    }
    arrays = {"mean": model.mean_, "trend": model.trend_, "centres": model.centres_,
              "alpha": model.alpha_, "index_matrix": model.index_matrix_,
              "index_goal": model.index_goal_}
    return arrays, meta


def model_from_state(cls: type[TrendKernelRegression], arrays: dict[str, np.ndarray],
                     meta: dict[str, Any]) -> TrendKernelRegression:
    """A fitted ``cls`` (:class:`~.model.TrendKernelRegression`) rebuilt from
    :func:`model_state` output (ValueError if malformed)."""
    try:
        if int(meta["version"]) > STATE_VERSION:
            raise ValueError(f"format version {meta['version']} is newer than supported")
        params = dict(meta["params"])
        for name in _HYPER:
            if params.get(name, "cv") != "cv":
                params[name] = float(params[name])
        model = cls(**params)
        n = int(meta["n_features_in"])
        model.n_features_in_ = n
        # Version 1 knew the quadratic trend only.
        model.trend_form_ = str(meta.get("trend_form", "quadratic"))
        if model.trend_form_ not in TREND_FORMS:
            raise ValueError(f"unknown trend_form {model.trend_form_!r}")
        single = model.trend_form_ == "single_index"
        model.trend_ridge_ = float(meta["trend_ridge"])
        model.length_scale_ = float(meta["length_scale"])
        model.kernel_ridge_ = float(meta["kernel_ridge"])
        model.offset_ridge_ = float(meta["offset_ridge"])
        model.scale_ = float(meta["scale"])
        model.y_mean_ = float(meta["y_mean"])
        model.y_scale_ = float(meta["y_scale"])
        model.mean_ = np.asarray(arrays["mean"], dtype=float).reshape(n)
        goal = meta.get("goal")  # absent before goal-centred models existed
        model.goal_ = None if goal is None else np.asarray(goal, dtype=float).reshape(n)
        bound = meta.get("min_curvature")  # absent before the goal's bowl had one
        model.min_curvature_ = None if bound is None else float(bound)
        trend = np.asarray(arrays["trend"], dtype=float).ravel()
        if single and int(meta["version"]) < 3:
            # Version 2's profile had no steepening columns: their weights are zero.
            trend = np.concatenate([trend, np.zeros(len(single_index.KNEES))])
        model.trend_ = trend.reshape(_n_index_weights() if single else _n_trend(n))
        model.index_matrix_ = np.asarray(arrays["index_matrix"] if single else
                                         np.zeros((0, n)), dtype=float).reshape(-1, n)
        model.index_goal_ = np.asarray(arrays["index_goal"] if single else np.zeros(0),
                                       dtype=float).reshape(n if single else 0)
        model.index_scale_ = float(meta["index_scale"]) if single else 0.0
        if single and (model.index_matrix_.shape != (n, n) or not model.index_scale_ > 0):
            raise ValueError("single-index trend needs an (n, n) index_matrix and "
                             "index_scale > 0")
        model.centres_ = np.asarray(arrays["centres"], dtype=float).reshape(-1, n)
        model.alpha_ = np.asarray(arrays["alpha"], dtype=float).reshape(len(model.centres_))
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"regressor state: bad or missing field ({err})") from None
    model.cv_scores_ = {}
    model.cv_standard_errors_ = {}
    model.cv_dof_ = {}
    model.cv_best_ = None
    model.cv_folds_ = None
    model._unpack()
    return model
