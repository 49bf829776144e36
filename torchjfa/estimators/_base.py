"""The interface shared by every estimator: scikit-learn style, fitted from `Moments`."""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Sequence

import torch

from .._validation import check_X, check_Xy
from ..stats import Moments, as_folds, kfold_moments

__all__ = ["LinearEstimator", "CONSTANT_COLUMN_RTOL"]

# A column whose variance about the mean (about zero without intercept) is below this fraction of
# its raw second moment is treated as constant: it carries no information and gets coefficient 0.
CONSTANT_COLUMN_RTOL = 1e-10


def _caller_level() -> int:
    """The ``stacklevel`` of `warnings.warn` that names the first frame outside this package
    (the user's ``fit`` call, however many estimator layers are in between)."""
    package = os.path.dirname(os.path.abspath(__file__))
    frame, level = sys._getframe(2), 2  # stacklevel 2 is the warning function's caller
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level


class LinearEstimator:
    """Base class of the linear estimators.

    Subclasses store keyword-only hyper-parameters in ``__init__`` and implement `_solve`, which
    sees the second moments of the informative (non-constant) columns only, and optionally
    `_check_params`. Hyper-parameter selection by cross-validation is done on *fold moments*:
    `fit` splits the data into ``cv`` contiguous folds; `fit_moments` takes either one
    `Moments` (no CV possible, the estimator must then be given its hyper-parameter) or a
    sequence of `Moments` used as folds.

    The protocol that the library's flow (`torchjfa.identification.fit`, `jackknife`) relies on,
    and that a third-party estimator implements (registered with
    `torchjfa.estimators.register`):

    - ``fit_moments(moments)`` with a `Moments` or a sequence of fold `Moments`, returning
      ``self`` with ``coef_`` ``(d,)`` set;
    - `needs_folds`, a read-only property: True when the estimator, as configured, chooses a
      hyper-parameter by cross-validation over fold moments and so must be given folds;
    - ``cv``: the number of folds to give it then (contiguous blocks of the samples).

    Attributes (after fitting):
        coef_: shape ``(d,)``, float64.
        intercept_: 0-d float64 tensor (0 when ``fit_intercept=False``).
        n_features_in_: d.
    """

    #: the hyper-parameter that cross-validation chooses (for messages)
    _cv_parameter = "the hyper-parameter"

    def __init__(self, *, fit_intercept: bool = True, cv: int = 5) -> None:
        self.fit_intercept = fit_intercept
        self.cv = cv

    # -------------------------------------------------------------- public API
    def fit(self, X, y, weights=None):
        """Fit from raw data, shape ``(n, d)`` and ``(n,)``. Returns ``self``."""
        # NaN and inf are caught by `Moments.update` from the statistics it forms anyway (a
        # separate isfinite pass over X cost three times the statistics themselves)
        X, y, weights = check_Xy(X, y, weights, finite=False)
        if self.needs_folds:
            if X.shape[0] < 2:
                raise ValueError(
                    f"{type(self).__name__} chooses {self._cv_parameter} by {self.cv}-fold "
                    f"cross-validation, which needs at least 2 rows (one per fold; {self.cv} for "
                    f"{self.cv} folds, and many more than the {X.shape[1]} columns for a useful "
                    f"choice); got {X.shape[0]}. Give more rows, or set {self._cv_parameter}="
                )
            return self.fit_moments(kfold_moments(X, y, min(self.cv, X.shape[0]), weights))
        return self.fit_moments(Moments.from_data(X, y, weights))

    def fit_moments(self, moments: Moments | Sequence[Moments]):
        """Fit from sufficient statistics. Returns ``self``.

        Args:
            moments: a `Moments`, or a sequence of `Moments` of disjoint folds of the data
                (their sum is the training set; estimators that choose a hyper-parameter by
                cross-validation use the folds).
        """
        total, folds = as_folds(moments)
        self._check_params(total.n_features)
        if folds is not None and len(folds) < 2 and self.needs_folds:
            raise ValueError(f"cross-validation needs at least 2 fold moments, got {len(folds)}")
        if not float(total.n) > 0:
            raise ValueError("cannot fit on Moments with no samples (total weight 0)")
        if folds is None and self.needs_folds:
            raise ValueError(
                f"{type(self).__name__} chooses its hyper-parameter by cross-validation and needs "
                "fold moments: pass a list of Moments (e.g. from torchjfa.kfold_moments), or set "
                "the hyper-parameter explicitly"
            )
        active = self._active_columns(total)
        self._warn_if_underdetermined(total, active)
        if folds is not None:
            folds = [f.select(active) for f in folds]
        coef_active = self._solve(total.select(active), folds)
        coef = torch.zeros(total.n_features, dtype=torch.float64, device=total.xtx.device)
        coef[active] = coef_active.to(torch.float64)
        self.coef_ = coef
        self.n_features_in_ = total.n_features
        if self.fit_intercept:
            self.intercept_ = total.mean_y - total.mean_x @ coef
        else:
            self.intercept_ = torch.zeros((), dtype=torch.float64, device=coef.device)
        return self

    def predict(self, X) -> torch.Tensor:
        """Predictions ``X coef_ + intercept_``, shape ``(n,)``, in ``X``'s dtype."""
        self._check_fitted()
        X = check_X(X, n_features=self.n_features_in_)
        return X @ self.coef_.to(X) + self.intercept_.to(X)

    @property
    def needs_folds(self) -> bool:
        """Whether `fit_moments` must be given fold `Moments` (a sequence of ``cv`` of them).

        True when the estimator, with its hyper-parameters as set, chooses one of them by
        cross-validation over the folds (e.g. `Lasso` without ``alpha``, `PLS` without
        ``n_components``); False (the default) when one `Moments` of all the data suffices.
        Subclasses that cross-validate override it.
        """
        return False

    # -------------------------------------------------------------- for subclasses
    def _check_params(self, n_features: int) -> None:
        """Raise ``ValueError`` (or ``TypeError``) on invalid hyper-parameters; called by
        `fit_moments` before anything is solved. ``n_features``: the number of inputs d."""

    def _solve(self, moments: Moments, folds: list[Moments] | None) -> torch.Tensor:
        """Coefficients of the informative columns, from their moments. Shape ``(d_active,)``."""
        raise NotImplementedError

    def _centered(self, moments: Moments):
        """``(Sxx, Sxy, Syy, n)``: second moments about the mean if fitting an intercept."""
        sxx, sxy, syy = moments.second_moments(center=self.fit_intercept)
        return sxx, sxy, syy, moments.n

    def _active_columns(self, moments: Moments) -> torch.Tensor:
        raw = torch.diagonal(moments.xtx)
        spread = torch.diagonal(moments.second_moments(center=self.fit_intercept)[0])
        active = spread > CONSTANT_COLUMN_RTOL * raw
        if not bool(active.any()):
            raise ValueError("every input column is constant; there is nothing to regress on")
        return active

    def _warn_if_underdetermined(self, moments: Moments, active: torch.Tensor) -> None:
        """Warn, once per fit, when there are fewer rows than parameters to estimate.

        The moments of n rows have rank at most n (n - 1 centred), so fewer rows than
        parameters leave infinitely many answers that fit the data equally well: every
        estimator then returns one picked by its regulariser, prior or numerics (a minimum-norm
        solution, or everything shrunk to ~0), not one the data chose. Rank deficiency with
        enough rows is not warned about here: robot regressors always have combinations of
        parameters that no motion excites, and the base-parameter analysis reports those.
        ``n_rows`` 0 (moments built without a row count) skips the check.
        """
        n_rows = int(moments.n_rows)
        n_columns = int(active.sum())
        n_params = n_columns + (1 if self.fit_intercept else 0)
        if n_rows <= 0 or n_rows >= n_params:
            return
        what = f"{n_columns} columns" + (" and an intercept" if self.fit_intercept else "")
        warnings.warn(
            f"{type(self).__name__}: {n_rows} rows for {n_params} parameters ({what}): the data "
            "cannot determine them, and the coefficients are one of infinitely many answers "
            "that fit equally well (picked by the regulariser, the prior or round-off, not by "
            f"the data). Use at least {n_params} rows (many more for a useful estimate) or "
            "fewer columns.",
            UserWarning,
            stacklevel=_caller_level(),
        )

    def _check_fitted(self) -> None:
        if not hasattr(self, "coef_"):
            raise RuntimeError(f"{type(self).__name__} is not fitted yet; call fit() first")

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.endswith("_"))
        return f"{type(self).__name__}({params})"
