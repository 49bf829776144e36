"""Linear estimators fitted from sufficient statistics.

All share one scikit-learn-style interface (`LinearEstimator`): keyword-only hyper-parameters,
``fit(X, y)`` / ``fit_moments(moments)`` returning ``self``, ``coef_``, ``intercept_`` and
``predict(X)``. Use `BayesianJFA` when inputs are noisy (robot identification); the others are
the baselines the paper compares it with.

`make` builds one by the name the command line uses (``"bayes-jfa"``, ``"ols"``, ...;
`available` lists them) and `register` adds a third-party estimator under a new name; the
protocol it follows (``fit_moments``, ``coef_``, ``needs_folds``, ``cv``) is
`LinearEstimator`'s.
"""

from ._base import LinearEstimator as LinearEstimator
from ._bootstrap import bootstrap as bootstrap
from ._bootstrap import redraw_moments as redraw_moments
from ._jackknife import jackknife as jackknife
from ._jackknife import jackknife_std as jackknife_std
from ._jfa import JFA as JFA
from ._jfa import BayesianJFA as BayesianJFA
from ._lasso import Lasso as Lasso
from ._linear import OLS as OLS
from ._linear import TLS as TLS
from ._linear import Ridge as Ridge
from ._pls import PLS as PLS
from ._registry import available as available
from ._registry import make as make
from ._registry import register as register
from ._registry import takes as takes
from ._stepwise import Stepwise as Stepwise
