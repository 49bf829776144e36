"""Linear estimators fitted from sufficient statistics.

All share one scikit-learn-style interface (`LinearEstimator`): keyword-only hyper-parameters,
``fit(X, y)`` / ``fit_moments(moments)`` returning ``self``, ``coef_``, ``intercept_`` and
``predict(X)``. Use `BayesianJFA` when inputs are noisy (robot identification); the others are
the baselines of the seed paper.
"""

from ._base import LinearEstimator as LinearEstimator
