"""What the executor checks about a model when it loads it, ROS-free.

What a model file can record that makes its runs go wrong although it loads:

* *a forced model*: ``policy-align learn --force`` (the learner's ``force:=true``) writes
  a fit that ``learn`` refused (no better than a zero policy, no minimum, ...) and records
  that in the header's ``training.pipeline`` block (``forced``, ``refusals``;
  :mod:`policy_align_ros.data.pipeline`). Such a model drove a UR10 away from its goal
  until the extrapolation guard stopped it. The executor refuses to arm it
  (:meth:`~policy_align_ros.control.step.ControlStep.model_check`,
  :data:`~policy_align_ros.control.causes.ZeroCause.FORCED_MODEL`) unless
  ``allow_forced_model`` is set, and warns whenever one is loaded (:func:`model_refusals`,
  :func:`forced_model_refusal`, :func:`forced_model_warning`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

__all__ = ["forced_model_refusal", "forced_model_warning", "model_refusals"]

#: Stands for the refusals of a model whose file says it was forced but names none.
UNNAMED_REFUSAL = "(the model file names no refusal)"


def model_refusals(model) -> tuple[str, ...]:
    """Why ``learn`` refused ``model``, when its file records that it was written anyway.

    Parameters
    ----------
    model : PolicyAlign
        As loaded; its ``fit_summary_["pipeline"]`` is the learn pipeline's summary
        (``forced``, ``refusals``).

    Returns
    -------
    tuple of str
        The refusals of a model recorded as forced (``forced`` true, or refusals recorded:
        a refused fit is only written when forced); empty for a model that passed every
        gate, and for one written without the learn pipeline (``PolicyAlign.save``).
    """
    pipeline = (getattr(model, "fit_summary_", None) or {}).get("pipeline")
    if not isinstance(pipeline, Mapping):
        return ()
    recorded = pipeline.get("refusals")
    refusals = (tuple(str(r) for r in recorded if str(r))
                if isinstance(recorded, list) else ())
    if pipeline.get("forced") is True or refusals:
        return refusals or (UNNAMED_REFUSAL,)
    return ()


def forced_model_refusal(refusals: Sequence[str]) -> str:
    """The ~/enable refusal (and ``zero_reason``) for a forced model whose ``refusals``
    :func:`model_refusals` gives: what learn said and the two ways on."""
    return (f"the model was refused by learn and written only because it was forced "
            f"(--force, or the learner's force:=true): {'; '.join(refusals)}. Learn a "
            f"model that passes (more or better demonstrations, without force), or, to run "
            f"this one anyway, set allow_forced_model (-p allow_forced_model:=true, or "
            f"policy-align param set /executor allow_forced_model true)")


def forced_model_warning(path: str, refusals: Sequence[str], allowed: bool) -> str:
    """The warning logged when a forced model (``refusals``) is loaded from ``path``;
    ``allowed``: ``allow_forced_model``."""
    then = ("allow_forced_model is set: ~/enable arms it" if allowed else
            "~/enable is refused until allow_forced_model is set or a model that passes "
            "is loaded")
    return (f"model {path} was refused by learn and written only because it was forced: "
            f"{'; '.join(refusals)}; {then}")
