"""What the data determine: base (identifiable) parameters from the moments.

The regression ``tau = X theta`` of a robot never determines every parameter: some enter only
in fixed linear combinations (a fixed-base arm's first link has one identifiable inertia,
about its axis; a link's mass enters the torques of its parents only together with their
moments), some columns are zero for any motion, and some combinations are excited so little by
a given log that the noise swamps them. `base_parameters` tells these apart from ``X^T X``
alone (`torchjfa.Moments`), so it works on logs of any length:

* **Structural** (eps-relative): the eigenvalues of the column-scaled ``C = D^-1 X^T X D^-1``
  (``D = sqrt(diag X^T X)``, so that the decision does not depend on the units) below
  ``rtol`` times the largest cannot be told from 0 in float64; their eigenvectors span the
  null space. The rank r is the number of base parameters. A Cholesky factorisation of C with
  diagonal pivoting (the same pivots as QR with column pivoting of the scaled X, since
  ``C = R^T R``) picks r independent columns B; every other column is ``X_dep = X_B beta``, so
  ``X theta = X_B (theta_B + beta theta_dep)``: the base parameters are
  ``theta_B + beta theta_dep`` (Gautier 1990, Khalil and Dombre's regrouping).
* **Poorly excited** (noise-relative): in coordinates where each parameter is measured in its
  kind's physical scale p (`parameter_scales`: the description's typical mass, first moment,
  inertia; for friction, the size that alone would explain the torque), a direction u with
  eigenvalue mu of ``P X^T X P`` is estimated by least squares with standard deviation
  ``sigma / sqrt(mu)`` (sigma^2: the residual variance per row). It is *determined* when that
  is below ``resolution`` (default 0.1: a tenth of the physical scale), i.e. when
  ``mu > sigma^2 / resolution^2``; otherwise the data leave it to the prior.

Each parameter is then ``"determined"`` (it lies in the determined subspace, so the data fix
it alone), ``"combination"`` (structurally only in combination with others), ``"poorly
excited"`` (identifiable in principle, but this log leaves it to the noise) or ``"not
excited"`` (its regressor column is zero, or below ``rtol`` of the energy of the largest
column of its kind: zero up to rounding).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from ..dynamics._parametrizations import resolve_layout
from ..estimators._jackknife import jackknife_std
from ..stats import Moments

__all__ = ["BaseParameters", "base_parameters", "parameter_scales", "parameter_kind"]

#: a parameter whose squared component in a subspace (orthonormal basis rows) exceeds this
#: belongs to it; eigenvectors of a cluster separated by a gap g from the rest are accurate to
#: about eps / g, far below this for any rank decision above
_LEVERAGE_TOL = 1e-6

#: coefficients of the column-scaled regrouping below this are rounding (see `base_parameters`)
_BETA_TOL = 1e-9

STATUSES = ("determined", "combination", "poorly excited", "not excited")


def parameter_kind(name: str) -> str:
    """A parameter's kind from its name: ``m``, ``mc`` (first moments), ``I`` (inertia) or the
    joint term's suffix (``fv``, ``fc``, ``fo``, ``ia``)."""
    short = name.rsplit(".", 1)[-1]
    if short.startswith("mc"):
        return "mc"
    if short.startswith("I"):
        return "I"
    return short


def parameter_scales(names, description=None, moments: Moments | None = None) -> torch.Tensor:
    """A physical scale for each parameter, the same for all parameters of a kind.

    The kind's root mean square over the description's values (``description``, e.g. a model's
    ``nominal_theta``) when that is positive; otherwise (friction and joint terms, which a
    description rarely gives, or no description) the median over the kind's excited columns
    of ``sqrt(y^T y / (X^T X)_kk)``, the size of that parameter that would alone produce the
    whole measured torque energy (from ``moments``); 1 when neither is available.

    Args:
        names: the ``n_params`` parameter names (``joint.m``, ``joint.mcx``, ``joint.fv``, ...).
        description: ``(n_params,)`` the description's parameters, or None.
        moments: `Moments` of the regression, or None.

    Returns:
        ``(n_params,)`` float64, positive, in each parameter's units.
    """
    names = list(names)
    kinds = [parameter_kind(n) for n in names]
    desc = None
    if description is not None:
        desc = torch.as_tensor(description, dtype=torch.float64).reshape(-1).cpu()
        if desc.numel() != len(names):
            raise ValueError(f"description has {desc.numel()} entries, names {len(names)}")
    data = None
    if moments is not None:
        diag = torch.diagonal(moments.xtx).to(torch.float64).cpu()
        yty = float(moments.yty)
        data = torch.where(diag > 0, (yty / diag.clamp_min(1e-300)).sqrt(), torch.nan)
    out = torch.ones(len(names), dtype=torch.float64)
    for kind in dict.fromkeys(kinds):
        idx = torch.tensor([i for i, k in enumerate(kinds) if k == kind])
        scale = 0.0
        if desc is not None:
            v = desc[idx]
            v = v[torch.isfinite(v)]
            scale = float(v.pow(2).mean().sqrt()) if v.numel() else 0.0
        if not scale > 0 and data is not None:
            v = data[idx]
            v = v[torch.isfinite(v) & (v > 0)]
            scale = float(v.median()) if v.numel() else 0.0
        out[idx] = scale if 0 < scale < math.inf else 1.0
    return out


@dataclass
class BaseParameters:
    """What `base_parameters` returns.

    Attributes:
        names: the ``n_params`` parameter names.
        rank: the number of base (structurally identifiable) parameters, r.
        n_determined: directions the log determines to ``resolution`` (<= rank).
        singular_values: ``(n_params,)`` of the column-scaled regression ``X D^-1``,
            descending (square roots of the eigenvalues of C), relative to the largest.
        condition_number: of the column-scaled base regression, ``s_1 / s_r`` (finite even
            when X^T X is singular: the structural null space is left out).
        independent: ``(r,)`` indices of the columns chosen as base parameters (pivot order).
        dependent: indices of the other columns.
        beta: ``(r, n_params - r)``: base parameters are ``theta[independent] + beta @
            theta[dependent]`` (units of the independent parameter per unit of the dependent).
        status: per parameter, one of ``"determined"``, ``"combination"``, ``"poorly
            excited"``, ``"not excited"``.
        noise_var: the residual variance per row sigma^2 used (torque^2).
        std: ``(r,)`` least-squares standard deviation of each base parameter,
            ``sigma sqrt(diag (X_B^T X_B)^-1)`` (white noise assumed: filtered noise is
            correlated, so this is a lower bound; the jackknife is the honest spread).
        scales: ``(n_params,)`` the physical scales p used for the noise decision.
        null_space: ``(n_params, n_params - r)`` orthonormal basis of the structural null space
            in column-scaled coordinates.
        rtol, resolution: the tolerances used.
    """

    names: tuple[str, ...]
    rank: int
    n_determined: int
    singular_values: torch.Tensor = field(repr=False)
    condition_number: float
    independent: tuple[int, ...] = field(repr=False)
    dependent: tuple[int, ...] = field(repr=False)
    beta: torch.Tensor = field(repr=False)
    status: tuple[str, ...] = field(repr=False)
    noise_var: float
    std: torch.Tensor = field(repr=False)
    scales: torch.Tensor = field(repr=False)
    null_space: torch.Tensor = field(repr=False)
    rtol: float = 0.0
    resolution: float = 0.1

    @property
    def n_params(self) -> int:
        return len(self.names)

    def counts(self) -> dict[str, int]:
        """How many parameters have each status."""
        return {s: sum(x == s for x in self.status) for s in STATUSES}

    def values(self, theta) -> torch.Tensor:
        """The base parameters of ``theta``, ``(..., n_params) -> (..., rank)``:
        ``theta[independent] + beta theta[dependent]``."""
        theta = torch.as_tensor(theta, dtype=torch.float64)
        ind = torch.tensor(self.independent, dtype=torch.long, device=theta.device)
        dep = torch.tensor(self.dependent, dtype=torch.long, device=theta.device)
        beta = self.beta.to(theta.device)
        out = theta[..., ind]
        if dep.numel():
            out = out + theta[..., dep] @ beta.T
        return out

    def jackknife_std(self, coefs) -> torch.Tensor:
        """``(rank,)`` the delete-one-block jackknife spread of the base parameters from the
        ``(K, n_params)`` leave-one-block-out coefficients (`torchjfa.estimators.jackknife`):
        unlike single parameters', these spreads are finite whatever the null space."""
        return jackknife_std(self.values(torch.as_tensor(coefs, dtype=torch.float64)))

    def combinations(self, *, min_coef: float = 1e-6) -> list[str]:
        """Each base parameter as text, ``"j1.Iyy + 0.16 j2.m + 0.4 j2.mcx"``; dependent terms
        with ``|beta|`` below ``min_coef`` times the largest of that row are left out."""
        out = []
        dep = list(self.dependent)
        for row, i in enumerate(self.independent):
            text = self.names[i]
            coefs = self.beta[row] if dep else torch.zeros(0)
            big = float(coefs.abs().max()) if coefs.numel() else 0.0
            for c, j in zip(coefs.tolist(), dep, strict=True):
                if big > 0 and abs(c) > min_coef * big:
                    text += f" {'+' if c > 0 else '-'} {abs(c):.4g} {self.names[j]}"
            out.append(text)
        return out

    def summary(self) -> str:
        """One line: the counts and the condition number."""
        c = self.counts()
        return (
            f"{self.rank} base parameters of {self.n_params} ({self.n_determined} determined to "
            f"{self.resolution:g} of their physical scale); condition number of the "
            f"column-scaled base regression {self.condition_number:.3g}; parameters: "
            + ", ".join(f"{v} {k}" for k, v in c.items())
        )

    def __str__(self) -> str:
        return self.summary()


def base_parameters(
    moments: Moments,
    layout=None,
    *,
    names=None,
    description=None,
    noise_var: float | None = None,
    rtol: float | None = None,
    resolution: float = 0.1,
) -> BaseParameters:
    """The base (identifiable) parameters of a regression, from its moments.

    See the module docstring for the two decisions (structural, eps-relative; poorly
    excited, noise-relative) and the four statuses.

    Args:
        moments: `Moments` of the regressor rows (``xtx``, ``xty``, ``yty``, ``n``).
        layout: a `ParameterLayout` or a model with ``.layout`` (for the names and, from a
            model, ``nominal_theta`` as the description); or give ``names``.
        names: parameter names, when there is no layout.
        description: ``(n_params,)`` the description's parameters for the physical scales
            (default: ``layout.nominal_theta`` when the layout is a model).
        noise_var: residual variance per row, torque^2; default the least-squares residual
            ``rss / (N - rank)`` of these moments.
        rtol: eigenvalues of the column-scaled X^T X below ``rtol`` times the largest count as
            0 (structural). Default ``1000 * n_params * eps``: X^T X is accumulated and
            decomposed in float64 with errors of a few ``n_params * eps`` of its largest
            eigenvalue, and the factor 1000 allows for the accumulation over many rows; a
            combination excited less than that (singular values below ~1e-5 of the largest)
            could not be estimated from the moments anyway.
        resolution: a direction is determined when its least-squares standard deviation is
            below this fraction of its physical scale (`parameter_scales`).

    Returns:
        A `BaseParameters`.

    Raises:
        TypeError: if ``moments`` is not a `Moments`.
        ValueError: on names that do not match, non-positive tolerances or data that excite
            nothing.
    """
    if not isinstance(moments, Moments):
        raise TypeError(f"moments must be a torchjfa.Moments, got {type(moments).__name__}")
    if layout is not None:
        names = resolve_layout(layout).parameter_names
        if description is None and hasattr(layout, "nominal_theta"):
            description = layout.nominal_theta
    if names is None:
        raise ValueError("give layout= (a ParameterLayout or a model) or names=")
    names = tuple(str(n) for n in names)
    d = moments.n_features
    if len(names) != d:
        raise ValueError(f"{len(names)} parameter names for moments with {d} features")
    eps = torch.finfo(torch.float64).eps
    rtol = 1000.0 * d * eps if rtol is None else float(rtol)
    if not (0 < rtol < 1) or not resolution > 0:
        raise ValueError(f"rtol must lie in (0, 1) and resolution be > 0, got {rtol}, {resolution}")
    M = moments.xtx.to(torch.float64).cpu()
    M = 0.5 * (M + M.T)
    M, diag, excited = _excited_columns(M, names, rtol)
    D = torch.where(excited, diag.sqrt(), torch.ones_like(diag))
    C = M / torch.outer(D, D)
    lam, vec = torch.linalg.eigh(C)  # ascending
    lam_max = float(lam[-1])
    null = lam <= rtol * lam_max
    rank = int((~null).sum())
    sv = (lam.flip(0).clamp_min(0) / lam_max).sqrt()
    cond = float(sv[0] / sv[rank - 1])
    null_space = vec[:, null]

    independent = _pivots(C, rank)
    dependent = tuple(i for i in range(d) if i not in set(independent))
    L, beta = _dependencies(C, D, list(independent), list(dependent))
    noise_var, std = _base_fit(moments, M, D, L, list(independent), noise_var)

    # the noise decision in physical-scale coordinates
    scales = parameter_scales(names, description, moments)
    n_det, status = _statuses(
        M,
        scales,
        excited,
        null_space,
        rank=rank,
        noise_var=noise_var,
        rtol=rtol,
        resolution=resolution,
    )
    return BaseParameters(
        names=names,
        rank=rank,
        n_determined=n_det,
        singular_values=sv,
        condition_number=cond,
        independent=independent,
        dependent=dependent,
        beta=beta,
        status=status,
        noise_var=noise_var,
        std=std,
        scales=scales,
        null_space=null_space,
        rtol=rtol,
        resolution=float(resolution),
    )


def _excited_columns(M: torch.Tensor, names, rtol: float):
    """Zero the columns (and rows) of M that the data do not excite.

    A column whose energy is below ``rtol`` of the largest of its kind (the same units: the
    test does not depend on the units of each kind) is zero up to rounding (a regressor entry
    that cancels in exact arithmetic comes out ~eps of its terms): scaling it to unit norm
    would make rounding look like a parameter of its own.

    Returns:
        ``(M, diag, excited)``: M ``(d, d)`` and its diagonal with those columns zeroed, and the
        ``(d,)`` bool mask of excited columns.

    Raises:
        ValueError: if no column is excited.
    """
    diag = torch.diagonal(M).clamp_min(0)
    kinds = [parameter_kind(n) for n in names]
    largest = {}
    for k, v in zip(kinds, diag.tolist(), strict=True):
        largest[k] = max(largest.get(k, 0.0), v)
    floor = torch.tensor([rtol * largest[k] for k in kinds], dtype=torch.float64)
    excited = diag > floor
    M = torch.where(excited.unsqueeze(0) & excited.unsqueeze(1), M, torch.zeros_like(M))
    diag = torch.where(excited, diag, torch.zeros_like(diag))
    if not bool(excited.any()):
        raise ValueError("the data excite no parameter (X^T X is zero): no motion?")
    return M, diag, excited


def _dependencies(C: torch.Tensor, D: torch.Tensor, ind: list[int], dep: list[int]):
    """How the dependent columns combine the base ones: ``X[:, dep] = X[:, ind] @ beta``.

    Args:
        C: ``(d, d)`` the column-scaled X^T X; D: ``(d,)`` the column scales.
        ind, dep: the base (independent) and dependent columns.

    Returns:
        ``(L, beta)``: the Cholesky factor of ``C``'s base block and ``(rank, n_dep)`` beta in
        the parameters' units.
    """
    L = torch.linalg.cholesky(C[ind][:, ind])
    if not dep:
        return L, C.new_zeros(len(ind), 0)
    beta_s = torch.cholesky_solve(C[ind][:, dep], L)
    # in scaled units a genuine dependency has coefficients of order 1; those of columns
    # that are independent of the base columns' span only by rounding are ~eps * cond
    beta_s = torch.where(beta_s.abs() > _BETA_TOL, beta_s, torch.zeros_like(beta_s))
    return L, beta_s * D[dep].unsqueeze(0) / D[ind].unsqueeze(1)


def _base_fit(moments: Moments, M, D, L, ind: list[int], noise_var):
    """Least squares on the base columns: the residual variance and the base parameters' spread.

    Args:
        M: ``(d, d)`` X^T X (unexcited columns zeroed); D: ``(d,)`` the column scales.
        L: Cholesky factor of the base block of the column-scaled X^T X.
        ind: the base (independent) columns.
        noise_var: given residual variance, or None for ``rss / (N - rank)``.

    Returns:
        ``(noise_var, std)``: float, torque^2, and ``(rank,)``.
    """
    M_bb = M[ind][:, ind]
    xty = moments.xty.to(torch.float64).cpu()
    Cinv = torch.cholesky_inverse(L)
    b_hat = (Cinv @ (xty[ind] / D[ind])) / D[ind]
    if noise_var is None:
        rss = float(moments.yty) - 2 * float(b_hat @ xty[ind]) + float(b_hat @ (M_bb @ b_hat))
        dof = float(moments.n) - len(ind)
        noise_var = max(rss, 0.0) / dof if dof > 0 else float("nan")
    noise_var = float(noise_var)
    std = (noise_var * torch.diagonal(Cinv)).clamp_min(0).sqrt() / D[ind]
    return noise_var, std


def _statuses(M, scales, excited, null_space, *, rank, noise_var, rtol, resolution):
    """The noise decision in physical-scale coordinates and each parameter's status.

    Returns:
        ``(n_determined, status)``: the number of determined directions and, per parameter,
        ``"not excited"``, ``"combination"``, ``"poorly excited"`` or ``"determined"``.
    """
    Mp = M * torch.outer(scales, scales)
    mu, U = torch.linalg.eigh(0.5 * (Mp + Mp.T))
    if math.isfinite(noise_var):
        det = mu > max(noise_var / resolution**2, rtol * float(mu[-1]))
    else:  # as many rows as base parameters: nothing to estimate the noise from
        det = mu > rtol * float(mu[-1])
    n_det = min(int(det.sum()), rank)
    off_det = 1.0 - U[:, det].pow(2).sum(1)  # squared distance of e_k from the subspace
    in_null = null_space.pow(2).sum(1)
    status = []
    for k in range(M.shape[0]):
        if not bool(excited[k]):
            status.append("not excited")
        elif float(in_null[k]) > _LEVERAGE_TOL:
            status.append("combination")
        elif float(off_det[k]) > _LEVERAGE_TOL:
            status.append("poorly excited")
        else:
            status.append("determined")
    return n_det, tuple(status)


def _pivots(C: torch.Tensor, rank: int) -> tuple[int, ...]:
    """The first ``rank`` pivots of a Cholesky factorisation of C with diagonal pivoting: each
    step takes the column with the largest residual norm after projecting out the columns
    chosen so far (exactly the pivots of QR with column pivoting of a factor of C); ties
    within 1e-9 relative go to the first."""
    d = C.shape[0]
    residual = torch.diagonal(C).clone()
    L = C.new_zeros(d, rank)
    chosen: list[int] = []
    for k in range(rank):
        r = residual.clone()
        if chosen:
            r[chosen] = -math.inf
        # the first column within 1e-9 of the largest residual: ties, which rounding would
        # break at random (the scaled diagonal starts all ones), go to the first column
        j = int(torch.nonzero(r >= r.max() * (1 - 1e-9))[0])
        col = (C[:, j] - L[:, :k] @ L[j, :k]) / r[j].clamp_min(1e-300).sqrt()
        L[:, k] = col
        residual = residual - col.pow(2)
        chosen.append(j)
    return tuple(chosen)
