"""Linear estimators fitted from sufficient statistics.

All share one scikit-learn-style interface (`LinearEstimator`): keyword-only hyper-parameters,
``fit(X, y)`` / ``fit_moments(moments)`` returning ``self``, ``coef_``, ``intercept_`` and
``predict(X)``. Use `BayesianJFA` when inputs are noisy (robot identification); the others are
the baselines of the seed paper.
"""

from ._base import LinearEstimator as LinearEstimator
from ._jackknife import jackknife as jackknife
from ._jfa import JFA as JFA
from ._jfa import BayesianJFA as BayesianJFA
from ._lasso import Lasso as Lasso
from ._linear import OLS as OLS
from ._linear import TLS as TLS
from ._linear import Ridge as Ridge
from ._pls import PLS as PLS
from ._stepwise import Stepwise as Stepwise
