"""Global regression of the LWPR family with an exact analytic gradient.

PolicyAlign (paper section III-D, eq. 16) fits a global model ``f(x)`` of the potential on
the aligned data and uses ``pi_hat(x) = -grad f(x)`` as the policy. The paper uses LWPR;
this package implements LWPR's prediction rule with a batch fit. PolicyAlign's default
regressor is ``TrendKernelRegression``; this one serves
:class:`~policy_align_ros.learning.baselines.naive.NaivePolicy`, the benchmark suite's
comparison and model files that name it.

Notation and units
------------------
``x`` in ``R^n`` is a state (state units, e.g. rad or m); ``y`` in ``R^d`` an output (for
the potential ``d = 1``, in state units^2 per second). Receptive field ``j`` has centre
``c_j`` and width ``h_j`` (state units): the global width ``h``, or its own with per-field
widths. Its weight is a Gaussian with a smooth polynomial cut-off at ``R = CUTOFF h``, so
that sums over neighbours are exact and sparse::

    g(s; h^2) = exp(-s / (2 h^2)) (1 - (s / R^2)^2)^2  for s < R^2, else 0;  s = ||x - c||^2

Model
-----
Each field carries a local linear model ``l_j(x) = beta_j0 + B_j (x - c_j)`` (``B_j`` of
shape (d, n)). The prediction is the normalised blend (LWPR)::

    f(x) = sum_j v_j(x) l_j(x) / sum_j v_j(x),
    v_j(x) = g(||x - c_j||^2 - t(x); H_j^2(t(x))),   t(x) = min_k ||x - c_k||^2

Subtracting ``t`` cancels in the Gaussian factor and keeps every point's nearest field at
weight 1, so the prediction stays finite far from the data; the blending width ``H_j`` is
``h_j`` near the data and grows like ``FAR_WIDENING * sqrt(t)`` far from it, so that the
gradient stays bounded there too (:func:`blend_width2`). ``grad f`` follows from the
quotient rule, exactly, and is tested against finite differences.

Floors (scalar outputs, i.e. potentials): the trajectories end at the minimum of ``f``, so
the fields there see data on one side only, and their linear extrapolations would carry
the descent of ``f`` past it. So each local model levels off below the lowest output
``y_min,j`` of its own data: ``l_j(x) = beta_j0 + phi_j(B_j (x - c_j))`` with
``phi_j(u) = u`` above ``a_j = y_min,j - beta_j0`` and ``a_j - w_j (1 - exp((u - a_j) /
w_j))`` below, ``w_j`` being ``FLOOR_SOFTNESS`` times the spread of ``B_j x`` over the
field's data (:func:`floored`, :func:`extrapolation_floors`). Ascending extrapolation stays
linear, so far from the data ``-grad f`` still points back to them.

Fit
---
Centres: a farthest-point cover of (a subsample of) the data with spacing ``h`` (LWPR's
rule of adding a field where none is active), capped at ``max_centers``. Each local model
is weighted ridge least squares on the points within ``R``: with weighted mean ``mu_j`` and
covariance ``Sigma_j``, ``(Sigma_j + ridge h_j^2 I) B_j^T = Cov_j(x, y)``. ``ridge`` is
dimensionless and acts on the slopes only; directions in which the local data do not vary
(the data lie on trajectory manifolds) get zero slope, as in LWPR's projection regression;
its default is ``1e-3 (n / 2)^2``. Neighbours come from a k-d tree in few dimensions and
from blocks of BLAS distances in many; the final fit uses at most ``MAX_FIT_POINTS``
samples, thinned along the trajectories, so its cost stops growing beyond that size.

Per-field widths (``widths``): field ``j`` may get ``h_j = h clip((rho_j / median rho) **
a, lo, hi)``, with ``rho_j`` the distance from its centre to its ``k``-th nearest sample
(:func:`adaptive_widths`; fields only narrow, where the data are dense).

Choice of the width
-------------------
``h`` is chosen by K-fold cross-validation over whole held-out trajectories, as errors
along one trajectory are correlated. The default criterion scores the *increments* of the
prediction between consecutive held-out samples, since the potential of a trajectory is
known only up to an offset. The chosen width is the CV optimum divided by
``GRADIENT_NARROWING``, as the gradient wants narrower fields than the values. With
``widths="cv"`` (default), per-field widths are kept when their CV error at the
CV-optimal width is lower than that of the global width.

Modules: :mod:`.kernels` (field weights), :mod:`.centres` (cover, neighbour index, per-field
widths), :mod:`.fields` (local statistics, ridge solves, floors), :mod:`.blend`
(prediction and gradient), :mod:`.cv` (choice of the width), :mod:`.model` (the estimator
and its model-file state).
"""

from policy_align_ros.learning.baselines.local_linear.model import LocalLinearRegression

__all__ = ["LocalLinearRegression"]
