"""What a global model of the potential must provide to PolicyAlign (``docs/design.md``
section 3).

Notation: ``N`` training samples of ``n`` state coordinates (state units); ``m`` query
states.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["Regressor"]


@runtime_checkable
class Regressor(Protocol):
    """A regressor of the aligned potential with an analytic gradient and a saved state.

    A class following it is registered with
    :func:`~policy_align_ros.learning.regressors.registry.register`, so that a model file,
    which names its regressor's class, loads again. A regressor may also take
    ``fit(..., free_groups=ids)`` (demonstrations whose offsets it re-fits freely; see
    :func:`~policy_align_ros.learning.regressors.registry.takes_free_groups`).
    """

    def fit(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None
            ) -> Regressor:
        """Fit on states ``X`` (N, n), targets ``y`` (N,) and the demonstration of every
        sample ``groups`` (N,) of int (``None``: one demonstration); return ``self``."""
        ...

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Model output ``f(x)``, shape (m,), at states ``X`` (m, n)."""
        ...

    def gradient(self, X: np.ndarray) -> np.ndarray:
        """``grad_x f(x)``, shape (m, n), in output units per state unit."""
        ...

    def get_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Numeric arrays and a JSON-able header that rebuild the fitted model exactly."""
        ...

    @classmethod
    def from_state(cls, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Regressor:
        """Rebuild a fitted model from :meth:`get_state`'s output (ValueError if
        malformed)."""
        ...
