"""Joint factor analysis regression with input noise: maximum likelihood (`JFA`) and Bayesian.

The model of the paper (Ting, Mistry, Peters, Schaal, Nakanishi, "A Bayesian approach to
nonlinear parameter identification for rigid body dynamics", RSS 2006), Fig. 1(b)/(c): every
input ``x_m`` is a noisy view ``w_xm t_m + noise`` of a hidden noiseless input ``t_m``, the
output is ``y = sum_m z_m + noise`` with ``z_m = w_zm t_m + noise``. Use these estimators when
the regressors themselves are noisy (joint velocities and accelerations of a robot): `BayesianJFA`
also prunes irrelevant and redundant inputs (automatic relevance determination).

Both are fitted from the sufficient statistics ``N, X^T X, X^T y, y^T y`` alone: `JFA` at the
closed-form maximum of its likelihood, `BayesianJFA` by Newton steps on its variational bound
with prune moves, which converge in tens to hundreds of iterations where the plain EM
(``method="em"``, kept as the reference) needs thousands. The bound has several optima where
inputs are redundant or irrelevant; `BayesianJFA` fits from several starts (``n_starts``) and
keeps the highest bound. ``docs/theory.md`` derives the model,
the bound, the updates and the optimiser; the code cites its equations. This module holds the
estimators (checks, standardisation, results in the caller's units); the maths is in
``_jfa_model.py`` (the model, its E-step, updates and bounds), ``_jfa_newton.py`` (the Newton
optimiser and its loop), ``_jfa_prune.py`` (its prune move) and ``_jfa_em.py`` (plain EM and
maximum likelihood's closed form).

Known limit (``docs/theory.md``, "What the data do not decide"): the de-noised slope
``w_z / w_x`` is not identified from second moments; the prior (or the starting point, for
`JFA`) picks it. Pass ``input_noise`` (a known or estimated noise variance per input, e.g. from
repeated excitation periods) to hold ``psi_x`` fixed and make it identified.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import replace

import torch

from .._util import progress_bar
from .._validation import as_tensor, check_finite, check_X
from ..stats import Moments, as_folds
from . import _jfa_model as jm
from ._base import LinearEstimator
from ._jfa_em import ml_closed_form, run_em
from ._jfa_newton import run_newton

__all__ = ["JFA", "BayesianJFA"]

# ard="output": the fixed prior precision of w_x in standardised units (the data pin w_x^2 to
# var(x) - psi_x once psi_x is known; this only keeps the prior proper)
_OUTPUT_ARD_WX_PRECISION = 1e-8
_ROUNDOFF_RMS = 1e-10
_BOUND_ROUNDOFF = 64 * 2.0**-52  # relative round-off of a bound (as the Newton loop's)
# an input is relevant while <alpha_m> is below this (standardised units): its loadings' prior
# spread above 0.01 of the unit variances; a pruned one is far above (1e6-1e7 on Fig. 2 data)
_RELEVANT_BELOW = 1e4
# method -> the fit, from the state after the first sweep
_FITS = {"newton": run_newton, "em": run_em, "closed_form": ml_closed_form}


def _check_noise_below_variance(noise, active, variance, centred: bool) -> None:
    """Refuse input noise at or above a column's variance: the model splits each column's
    variance into signal ``w_x^2`` and noise ``psi_x``, so ``psi_x >= var`` leaves no signal
    (the loop would clamp it and return nonsense)."""
    columns = torch.nonzero(active).flatten()
    # a column whose RMS is below 1e-10 of the largest column's is round-off (a structurally
    # zero regressor column of a robot: 1e-16 m/s^2): a noise estimated on it is round-off too
    roundoff = variance < _ROUNDOFF_RMS**2 * variance.max()
    bad = (noise[columns] >= variance) & ~roundoff
    if not bool(bad.any()):
        return
    where = "about its mean" if centred else "about zero (fit_intercept=False)"
    listed = [
        f"column {int(c)}: noise {float(noise[c]):.4g} >= variance {float(v):.4g}"
        for c, v in zip(columns[bad].tolist(), variance[bad].tolist(), strict=True)
    ]
    more = f" (and {len(listed) - 8} more)" if len(listed) > 8 else ""
    raise ValueError(
        "input_noise must be below the variance of each input column (the noise is part of "
        f"what was measured); {', '.join(listed[:8])}{more}, variance {where}. Check the "
        "units of input_noise (variances, squared units of each column, not standard "
        "deviations) and that it was estimated on these columns"
    )


def _best_start(bounds: Sequence[torch.Tensor], tol: float, n: float) -> int:
    """The start whose fit ends with the highest bound; the first start (eq. 10's) is kept
    unless another's bound is higher by more than ``tol * max(|L|, N)`` and the bound's
    round-off, so that optima the bound does not tell apart give the default start's answer."""
    values = [float(b) for b in bounds]
    best = 0
    for i, v in enumerate(values[1:], start=1):
        level = max(abs(values[best]), n, 1.0)
        if v > values[best] + max(tol, _BOUND_ROUNDOFF) * level:
            best = i
    return best


class _JFABase(LinearEstimator):
    """The shared fitting code; see `JFA` and `BayesianJFA`."""

    _methods: tuple[str, ...] = ()

    # ------------------------------------------------------------------ public API
    def fit_moments(self, moments: Moments | Sequence[Moments]):
        """Fit from sufficient statistics (a `Moments`, or fold `Moments` that are summed):
        the standardised moments by the fit ``method`` names, from the state after the first
        EM sweep (eq. 10), mapped back to the caller's units. `BayesianJFA`'s Newton fit
        runs ``n_starts`` starts and keeps the one whose bound ends highest (`_best_start`).

        Returns:
            ``self``.
        """
        S, psx_fixed, *units = self._prepare(moments)
        cfg = self._settings()
        kw = dict(max_iter=int(self.max_iter), tol=float(self.tol), coef_tol=float(self.coef_tol))
        bar = progress_bar(total=int(self.max_iter), desc=type(self).__name__, enabled=self.verbose)
        # plain EM is the reference: the one start of eq. 10, whatever n_starts says
        n_starts = int(getattr(self, "n_starts", 1)) if self.method == "newton" else 1
        if self.verbose:
            bar.total = int(self.max_iter) * n_starts
        with bar:
            results = []
            for start in range(n_starts):  # start 0 is eq. 10's, the others perturb it
                gen = torch.Generator().manual_seed(start) if start else None
                st = jm.first_sweep(S, psx_fixed, cfg, gen)
                results.append(
                    _FITS[self.method](S, st, cfg, bar=bar if self.verbose else None, **kw)
                )
            if self.verbose:
                bar.total = bar.n  # converged before the cap: the bar ends full
                bar.refresh()
        best = _best_start([r.history[-1] for r in results], float(self.tol), float(S.n))
        self._store(results[best], *units)
        if cfg.bayes:  # each start's final bound, in the caller's units as lower_bound_
            shift = self.lower_bound_[-1] - results[best].history[-1]
            self.start_bounds_ = torch.stack([r.history[-1] for r in results]) + shift
            self.best_start_ = best
        return self

    def fit_batch(self, problems: Sequence[Moments | Sequence[Moments]]) -> list:
        """Fit one copy of this estimator to each of several problems (the jackknife's refits,
        cross-validation folds, the trials of an experiment): `fit_moments` on each, so each
        result is its single fit's.

        Args:
            problems: a sequence of `Moments` (or of fold `Moments`, summed), all with the
                same number of features.

        Returns:
            A list of fitted copies of ``self`` (same hyper-parameters), in the order of
            ``problems``; ``self`` is not modified.
        """
        problems = list(problems)
        if not problems:
            raise ValueError("fit_batch needs at least one problem")
        widths = sorted({int(as_folds(p)[0].n_features) for p in problems})
        if len(widths) > 1:
            raise ValueError(f"fit_batch needs problems of one width; got {widths} features")
        return [copy.deepcopy(self).fit_moments(p) for p in problems]

    def _prepare(self, moments: Moments | Sequence[Moments]):
        """Check the settings and the statistics of one problem and standardise them:
        ``(S, psx_fixed, active, sx, sy, m, total)`` (see `_store`)."""
        total, _ = as_folds(moments)
        if not float(total.n) > 0:
            raise ValueError("cannot fit on Moments with no samples (total weight 0)")
        d = total.n_features
        self._check_params(d)
        noise = self._input_noise(d, total.xtx.device)
        active = self._active_columns(total)
        self._warn_if_underdetermined(total, active)
        m = total.select(active)
        sxx, sxy, syy, n = self._centered(m)
        sx = torch.sqrt(torch.diagonal(sxx) / n)  # input scales, caller's units
        sy = torch.sqrt(syy / n)
        if not float(sy) > 0:
            raise ValueError("y is constant (zero variance); there is nothing to regress")
        if noise is not None:
            _check_noise_below_variance(noise, active, sx * sx, self.fit_intercept)
        S = jm.Stats(sxx / torch.outer(sx, sx), sxy / (sx * sy), syy / (sy * sy), n)
        psx_fixed = None if noise is None else noise[active] / (sx * sx)
        return S, psx_fixed, active, sx, sy, m, total

    def predict(self, X, *, noiseless: bool = False) -> torch.Tensor:
        """Predictions, shape ``(n,)``, in ``X``'s dtype.

        Args:
            X: inputs, shape ``(n, d)``.
            noiseless: ``False`` (default) for noisy inputs, measured like the training inputs:
                ``X coef_noisy_ + intercept_noisy_`` (the paper's eq. 3, ``E[y | x]``). ``True``
                for noiseless inputs: ``X coef_ + intercept_`` (the paper's eq. 4).
        """
        self._check_fitted()
        X = check_X(X, n_features=self.n_features_in_)
        if noiseless:
            return X @ self.coef_.to(X) + self.intercept_.to(X)
        return X @ self.coef_noisy_.to(X) + self.intercept_noisy_.to(X)

    # ------------------------------------------------------------------ internals
    def _check_params(self, n_features: int | None = None) -> None:
        """Refuse bad hyper-parameters (``n_features`` is unused: the common signature)."""
        if isinstance(self.max_iter, bool) or int(self.max_iter) != self.max_iter:
            raise TypeError(f"max_iter must be an integer, got {self.max_iter!r}")
        if self.max_iter < 1:
            raise ValueError(f"max_iter must be at least 1, got {self.max_iter}")
        for name in ("tol", "coef_tol"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and v >= 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        for name in ("noise_floor", "noise_y_floor"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0 < v < 1):
                raise ValueError(f"{name} must be in (0, 1), got {v!r}")
        if self.method not in self._methods:
            raise ValueError(
                f"method must be one of {', '.join(map(repr, self._methods))}, got {self.method!r}"
            )

    def _input_noise(self, d: int, device) -> torch.Tensor | None:
        if self.input_noise is None:
            return None
        v = as_tensor(self.input_noise, name="input_noise", dtype=torch.float64, device=device)
        if tuple(v.shape) != (d,):
            raise ValueError(
                f"input_noise must have shape ({d},), one noise variance per input column, "
                f"got shape {tuple(v.shape)}"
            )
        check_finite(v, "input_noise")
        if bool((v < 0).any()):
            raise ValueError(
                f"input_noise holds variances and must be >= 0; got negative entries at "
                f"{torch.nonzero(v < 0).flatten().tolist()}"
            )
        return v

    def _settings(self) -> jm.Settings:
        return jm.Settings(
            bayes=False,
            noise_floor=float(self.noise_floor),
            noise_y_floor=float(self.noise_y_floor),
            fixed_x=self.input_noise is not None,
        )

    def _store(self, res: jm.Result, active, sx, sy, m: Moments, total: Moments) -> None:
        """Map the standardised solution back to the caller's units, zeros for constant columns."""
        d = total.n_features
        kw = {"dtype": torch.float64, "device": total.xtx.device}
        cfg = self._settings()
        st = res.state

        def full(v, fill=0.0):
            out = torch.full((d,), fill, **kw)
            out[active] = v
            return out

        self.coef_ = full(jm.coef(st, cfg) * sy / sx)
        self.coef_noisy_ = full(jm.predictor(st) * sy / sx)
        self.noise_x_ = full(st.psx * sx * sx)
        self.noise_z_ = full(st.psz * sy * sy)
        self.noise_y_ = st.psy * sy * sy  # 0-d tensor
        self.weights_z_ = full(st.mz * sy)  # <w_z> in y's units per unit-variance t
        self.weights_x_ = full(st.mx * sx)
        if cfg.bayes:
            self.relevance_ = full(cfg.shape / st.rate, math.inf)
            self.relevant_ = self.relevance_ < _RELEVANT_BELOW
            # first-order spread of w_z / w_x under the factorised posterior Q(w_z) Q(w_x)
            var = (st.vz + (st.mz / st.mx) ** 2 * st.vx) / (st.mx * st.mx)
            self.coef_std_ = full(torch.sqrt(var) * sy / sx)
        self.n_features_in_ = d
        self.active_ = active
        if self.fit_intercept:
            self.intercept_ = total.mean_y - total.mean_x @ self.coef_
            self.intercept_noisy_ = total.mean_y - total.mean_x @ self.coef_noisy_
        else:
            self.intercept_ = torch.zeros((), **kw)
            self.intercept_noisy_ = torch.zeros((), **kw)
        # the bound on log p(X, y) in the caller's units: the change of variables adds -N log|J|
        jac = m.n * (torch.log(sx).sum() + torch.log(sy))
        self.lower_bound_ = res.history - jac
        self.n_iter_ = res.n_iter
        self.stop_reason_ = jm.REASONS[res.reason]
        self.converged_ = self.stop_reason_ != "max_iter"


class JFA(_JFABase):
    """Probabilistic joint factor analysis regression by maximum likelihood (Fig. 1(b)).

    The model of `BayesianJFA` without the priors: ``w_z``, ``w_x`` and the noise variances are
    point estimates. Prefer `BayesianJFA` on ill-conditioned or redundant inputs.

    Args:
        max_iter: iteration cap of plain EM (``method="em"``, or where the closed form cannot
            be reached).
        tol: EM stops when the log-likelihood changes by at most ``tol * max(|L|, N)``.
        coef_tol: EM stops when ``||delta coef|| <= coef_tol ||coef||`` (standardised units).
        input_noise: optional known noise variance per input, shape ``(d,)``, caller's units
            (squared units of each column), below each column's variance. ``psi_x`` is then
            held fixed at it.
        noise_floor: lower bound of psi_x and psi_z, as a fraction of the variance of x_m / y.
        noise_y_floor: lower bound of psi_y, as a fraction of var(y) (the likelihood is flat
            along ``psi_y + sum psi_z``).
        method: ``"closed_form"`` (default): the maximum of the likelihood (each input's
            variance ``diag(X^T X) / N``, the predictor ``k`` = OLS, the residual variance
            ``RSS / N``; ``docs/theory.md``, eq. 19), at the point of the flat ridge of
            equally likely states where psi_x is the given noise or half of each column's
            variance; plain EM where the floors or the given noise make that optimum
            unreachable. ``"em"``: plain EM from the initialisation of eq. 10 (the ridge point
            EM drifts to).
        fit_intercept: centre ``X`` and ``y`` (inputs are always scaled to unit variance).
        verbose: show a progress bar.

    Attributes:
        coef_: ``(d,)`` the noiseless-input slope ``w_z / w_x`` (eq. 4), units of y per unit x.
        coef_noisy_: ``(d,)`` the noisy-input predictor ``E[y | x]`` (eq. 3).
        intercept_, intercept_noisy_: 0-d intercepts of ``coef_`` and ``coef_noisy_``.
        noise_x_, noise_z_: ``(d,)`` psi_x (column units squared) and psi_z (y units squared);
            0 for constant columns. noise_y_: 0-d psi_y (y units squared).
        weights_x_, weights_z_: ``(d,)`` the loadings in caller's units (t has unit variance).
        lower_bound_: ``(n_iter_,)`` the log-likelihood of (X, y) after each iteration, nats
            (closed form: after the first EM sweep from the initialisation, and at the optimum).
        n_iter_: iterations run.
        converged_: whether a tolerance stopped it.
        stop_reason_: ``"bound"``, ``"coef"`` or ``"max_iter"``.
    """

    _methods = ("closed_form", "em")

    def __init__(
        self,
        *,
        max_iter: int = 5000,
        tol: float = 1e-10,
        coef_tol: float = 1e-7,
        input_noise=None,
        noise_floor: float = 1e-6,
        noise_y_floor: float = 1e-6,
        method: str = "closed_form",
        fit_intercept: bool = True,
        verbose: bool = False,
    ) -> None:
        super().__init__(fit_intercept=fit_intercept)
        self.max_iter, self.tol, self.coef_tol = max_iter, tol, coef_tol
        self.input_noise, self.noise_floor = input_noise, noise_floor
        self.noise_y_floor, self.method, self.verbose = noise_y_floor, method, verbose


class BayesianJFA(_JFABase):
    """Bayesian joint factor analysis regression by variational Bayes (the paper, Fig. 1(c)).

    ``w_zm`` and ``w_xm`` share a precision ``alpha_m ~ Gamma(a0, b0)`` (or, with
    ``ard="output"``, it governs ``w_zm`` alone): an input that does not explain the output is
    pruned (``alpha_m`` large, both weights near 0), which regularises
    ill-conditioned, redundant and irrelevant inputs. Fitted from `Moments` only, by Newton
    steps with prune moves on the variational bound (``docs/theory.md``, eqs. 12-18).

    Args:
        max_iter: iteration cap (one iteration = one Newton or prune trial, or one plain EM
            sweep with ``method="em"``). The Newton optimiser converges in tens to a few
            hundred iterations (``scripts/bench_estimators.py`` prints them); plain EM needs
            thousands, often more than any cap.
        tol: the Newton optimiser has converged when a kept step changes the lower bound by
            at most ``tol * max(|L|, N)`` and no coordinate by more than ``coef_tol`` (checked
            once more with the damping at its floor), or when its step's gain is below the
            bound's round-off; it stops when then no prune move gains (eq. 16). Plain EM stops
            when the bound changes by at most ``tol * max(|L|, N)`` in a sweep. With ``tol =
            coef_tol = 0`` both run ``max_iter`` iterations.
        coef_tol: the largest change of a parameter in a converged Newton step (posterior means
            in standardised units, logs of the variances). Plain EM stops when
            ``||delta coef_|| <= coef_tol ||coef_||`` (standardised units). Plain EM's
            rate along the unidentified direction of the paper's eq. (4) is ``1 - O(1/N)``,
            so its answer moves with the iteration count and the chunking of the data; the
            Newton optimiser's converges quadratically and agrees whatever the chunking, to
            round-off, unless round-off early in the path led to another optimum of the bound
            (``docs/theory.md``, "Optima and round-off").
        a0: shape of the Gamma prior of every ``alpha_m`` (1e-8: nearly flat).
        b0: rate of the Gamma prior of every ``alpha_m`` (1e-8: nearly flat).
        input_noise: optional known noise variance of each input, shape ``(d,)``, in the
            caller's units (squared units of each column), e.g. half the variance of the
            difference between two repeated excitation periods. ``psi_x`` is then held fixed
            at it, which makes the paper's eq. (4) identified. Zeros are allowed (exact columns) and are
            raised to the noise floor; a noise at or above a column's variance is refused
            (``ValueError`` naming the columns).
        ard: which loadings the relevance precision ``alpha_m`` governs. ``"shared"`` (the
            paper's model, the default): ``w_zm`` and ``w_xm`` both. ``"output"``: ``w_zm``
            alone, with ``w_xm ~ N(0, 1e8)`` in standardised units (a proper but flat
            prior). Use ``"output"`` with ``input_noise``: once psi_x is known, the data pin
            ``w_xm^2`` to ``var(x_m) - psi_xm``, so a shared alpha_m cannot grow for an input
            that is measured well but does not matter for y, and such inputs are not pruned;
            with alpha_m on ``w_zm`` alone they are. Measured on the paper's Fig. 2 protocol
            at input SNR 2 (``docs/paper.md``): clean-test nMSE 0.08 instead of 0.11 with
            90 irrelevant inputs, and lower in every scenario. Without ``input_noise`` it is allowed but
            untested against the paper.
        noise_floor: lower bound of psi_x and psi_z as a fraction of the variance of x_m / y.
        noise_y_floor: lower bound of psi_y as a fraction of var(y). psi_y drifts towards 0
            (only ``psi_y + sum psi_z`` is identified) and ends at this floor; ``coef_`` moves
            with it by O(psi_y) (measured: 3e-4 relative between 1e-3 and the limit), while
            reaching a smaller floor takes many more iterations. Must be well below
            ``1 - R^2`` of the data.
        method: ``"newton"`` (default): the Newton optimiser; ``"em"``: plain variational EM
            sweeps (eqs. 3-8, the reference). Both keep the bound monotone.
        n_starts: how many starts the fit runs to convergence; it keeps the fit whose bound
            ends highest. The bound has one local optimum per pattern of pruned inputs, and
            which one a start reaches depends on the path: with redundant and irrelevant
            inputs the optima a few nats apart give clean-test nMSEs apart by up to a factor
            of ten (the paper's eq. 4 without ``input_noise`` most). Start 0 is eq. 10's;
            start ``s > 0`` perturbs it with a generator seeded ``s`` (`_jfa_model.
            initial_state`: each learned ``psi_xm`` uniform in (0.2, 0.8), each ``<w_zm>``
            times ``exp(u)``, ``u`` normal with standard deviation 1/2), so a fit is
            reproducible. The rule: the highest final bound wins; start 0 is kept unless
            another ends higher by more than ``tol * max(|L|, N)`` (and the bound's
            round-off), so optima the bound cannot tell apart give start 0's answer. The
            bound is the model's evidence for the data: the rule is the model's own choice
            between the optima, not a score on held-out data. Plain EM (``method="em"``, the
            reference) runs start 0 alone. Fits with one optimum give every start's answer;
            the fit takes ``n_starts`` times as long. What more starts gain on the paper's
            synthetic data: the benchmarks page (``scripts/reproduce_fig2.py``).
        fit_intercept: centre ``X`` and ``y`` (inputs and output are always scaled to unit
            variance inside; results are mapped back).
        verbose: show a progress bar.

    Attributes:
        coef_: ``(d,)`` the noiseless-input estimate of the paper's eq. (4), ``<w_z><w_x> /
            <w_x^2>`` (``docs/theory.md``, eq. 11), for
            system identification; 0 for pruned and for constant columns. It is close to
            ``coef_noisy_ / (1 - noise_x_ / var(x))``: the predictor de-noised column by column
            by the reliability the model attributes to each column. Without ``input_noise``
            that split is not identified (the module docstring) and the relevance prior sets
            it: a column that matters little for y has its ``w_x`` shrunk and most of its
            variance put into ``noise_x_``, so its ``coef_`` is the predictor's weight
            amplified many times. Measured (``tests/estimators/test_bayes_jfa.py``): an
            irrelevant column correlated 0.5 with a relevant one, all inputs at SNR 11, gets
            ``coef_`` 1.4 where OLS and ``coef_noisy_`` give 0.14 (E[y | x] rightly uses it as
            a proxy for its noisy neighbour) and 90% of its variance is called noise (truth:
            8%); with ``input_noise`` given it gets 0.16. Give ``input_noise`` whenever
            ``coef_`` is to be read as physical parameters.
        coef_noisy_: ``(d,)`` the noisy-input predictor of the paper's eq. (3) (``= k``,
            ``E[y | x]``).
        intercept_, intercept_noisy_: 0-d intercepts of ``coef_`` and of ``coef_noisy_``.
        noise_x_: ``(d,)`` psi_x, input noise variances (each column's units squared).
        noise_z_: ``(d,)`` psi_z (y's units squared). noise_y_: 0-d psi_y (y's units squared).
        coef_std_: ``(d,)`` posterior spread of ``coef_``: the first-order (delta-method)
            standard deviation of ``w_z / w_x`` under the factorised posterior
            ``Q(w_z) Q(w_x)``, units of ``coef_``. Mean-field posteriors are too narrow
            when the loadings are correlated a posteriori; read it as a lower bound.
        relevance_: ``(d,)`` posterior mean ``<alpha_m>``, the prior precision of the loadings
            of input m in standardised units (x_m and y scaled to unit variance, so
            dimensionless): about 1 to 10 for a relevant input, orders of magnitude larger for
            an irrelevant one; ``inf`` for constant columns.
        relevant_: ``(d,)`` bool, the relevance decisions: ``relevance_`` below 1e4 (the
            loadings' prior standard deviation above 0.01 of the unit scales); a pruned input
            ends orders of magnitude above it (1e6 to 1e7 on the paper's synthetic data).
        start_bounds_: ``(n_starts,)`` the final bound of each start (caller's units, nats,
            as ``lower_bound_``); ``best_start_``: the start kept (``n_starts``).
        weights_x_, weights_z_: ``(d,)`` posterior means of the loadings, caller's units.
        lower_bound_: ``(n_iter_,)`` float64, the variational lower bound on ``log p(X, y)``
            (caller's units, nats) after each iteration; non-decreasing (a Newton step whose
            gain is below the bound's round-off is kept unless the bound falls by more than
            its round-off).
        n_iter_: iterations run. converged_: whether a tolerance stopped it. stop_reason_:
            ``"bound"``, ``"coef"`` or ``"max_iter"``. ``lower_bound_``, ``n_iter_``,
            ``converged_`` and ``stop_reason_`` are those of the start kept.
        active_: ``(d,)`` bool, the non-constant columns that were modelled.

    Example:
        >>> est = BayesianJFA(input_noise=noise_var).fit(X, y)  # doctest: +SKIP
        >>> theta = est.coef_                                   # doctest: +SKIP
    """

    _methods = ("newton", "em")

    def __init__(
        self,
        *,
        max_iter: int = 20000,
        tol: float = 1e-12,
        coef_tol: float = 1e-9,
        a0: float = 1e-8,
        b0: float = 1e-8,
        input_noise=None,
        ard: str = "shared",
        noise_floor: float = 1e-6,
        noise_y_floor: float = 1e-3,
        method: str = "newton",
        n_starts: int = 4,
        fit_intercept: bool = True,
        verbose: bool = False,
    ) -> None:
        super().__init__(fit_intercept=fit_intercept)
        self.max_iter, self.tol, self.coef_tol = max_iter, tol, coef_tol
        self.input_noise, self.noise_floor = input_noise, noise_floor
        self.noise_y_floor, self.method, self.verbose = noise_y_floor, method, verbose
        self.a0, self.b0, self.ard, self.n_starts = a0, b0, ard, n_starts

    def _check_params(self, n_features: int | None = None) -> None:
        super()._check_params(n_features)
        for name in ("a0", "b0"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if self.ard not in ("shared", "output"):
            raise ValueError(f"ard must be 'shared' or 'output', got {self.ard!r}")
        if isinstance(self.n_starts, bool) or int(self.n_starts) != self.n_starts:
            raise TypeError(f"n_starts must be an integer, got {self.n_starts!r}")
        if self.n_starts < 1:
            raise ValueError(f"n_starts must be at least 1, got {self.n_starts}")

    def _settings(self) -> jm.Settings:
        return replace(
            super()._settings(),
            bayes=True,
            a0=float(self.a0),
            b0=float(self.b0),
            shared_ard=self.ard == "shared",
            wx_precision=_OUTPUT_ARD_WX_PRECISION,
        )
