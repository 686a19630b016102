"""The default regressor: a quadratic trend plus a Gaussian-kernel residual, its
hyperparameters chosen by cross-validation over whole demonstrations.

- :mod:`.model`: :class:`TrendKernelRegression` (parameters, fit, prediction);
- :mod:`.state`: what a model file holds of it, and the model rebuilt from that;
- :mod:`.cv`: the cross-validated search and its selection rules;
- :mod:`.grams`: the per-fold sums the CV scores from;
- :mod:`.solvers`: the penalised least-squares solves and the effective degrees of freedom;
- :mod:`.lapack`: the small dense factorisations and solves, straight from LAPACK;
- :mod:`.features`: the trend's, the kernel's and the single-index trend's features;
- :mod:`.single_index`: the single-index trend (a profile of one fitted quadratic form);
- :mod:`.stacked`: several fitted models' gradients in one evaluation.
"""

from policy_align_ros.learning.regressors.trend_kernel.features import quadratic_features
from policy_align_ros.learning.regressors.trend_kernel.grams import shared_sums
from policy_align_ros.learning.regressors.trend_kernel.model import TrendKernelRegression
from policy_align_ros.learning.regressors.trend_kernel.solvers import effective_dof

__all__ = ["TrendKernelRegression", "effective_dof", "quadratic_features", "shared_sums"]
