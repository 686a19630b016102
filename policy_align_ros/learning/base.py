"""The estimator contract every model of the learning core shares (scikit-learn's).

Hyperparameters are keyword arguments of ``__init__``, stored untouched under their own
names; ``get_params``, ``set_params`` and ``repr`` are derived from that signature, never
written by hand, so a new parameter cannot be forgotten in one of them. Learnt attributes
end in ``_`` and exist only after ``fit`` (or ``load``): :func:`check_is_fitted` is the one
test of that.
"""

from __future__ import annotations

import inspect
from typing import Any

__all__ = ["BaseEstimator", "NotFittedError", "check_is_fitted"]


class NotFittedError(ValueError):
    """A model was used before ``fit`` (or ``load``)."""


class BaseEstimator:
    """``get_params``/``set_params``/``repr`` from the signature of ``__init__``."""

    @classmethod
    def _param_names(cls) -> list[str]:
        signature = inspect.signature(cls.__init__)
        names = []
        for p in signature.parameters.values():
            if p.name == "self":
                continue
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                raise TypeError(f"{cls.__name__}.__init__ may not take *args or **kwargs")
            names.append(p.name)
        return names

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Constructor arguments, as given.

        With ``deep``, the parameters of a nested estimator appear as well, under
        ``name__param`` (as in scikit-learn).
        """
        params = {name: getattr(self, name) for name in self._param_names()}
        if deep:
            for name, value in list(params.items()):
                if isinstance(value, BaseEstimator):
                    for key, sub in value.get_params(deep=True).items():
                        params[f"{name}__{key}"] = sub
        return params

    def set_params(self, **params: Any) -> BaseEstimator:
        """Set constructor arguments (``name__param`` reaches a nested estimator)."""
        valid = self._param_names()
        nested: dict[str, dict[str, Any]] = {}
        for key, value in params.items():
            name, _, sub = key.partition("__")
            if name not in valid:
                raise ValueError(
                    f"{type(self).__name__}.set_params: unknown parameter {name!r}; "
                    f"valid: {valid}"
                )
            if sub:
                nested.setdefault(name, {})[sub] = value
            else:
                setattr(self, name, value)
        for name, sub_params in nested.items():
            inner = getattr(self, name)
            if not isinstance(inner, BaseEstimator):
                raise ValueError(
                    f"{type(self).__name__}.set_params: {name!r} is {inner!r}, which has "
                    "no parameters to set"
                )
            inner.set_params(**sub_params)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params(deep=False).items())
        return f"{type(self).__name__}({args})"


def check_is_fitted(estimator: Any, attribute: str) -> None:
    """Raise :class:`NotFittedError` unless ``estimator`` has the learnt ``attribute``."""
    if not hasattr(estimator, attribute):
        name = type(estimator).__name__
        raise NotFittedError(f"this {name} is not fitted yet: call fit() or load()")
