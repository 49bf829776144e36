"""The regression equations of a floating-base robot in contact with its surroundings.

A walking robot's equation of motion, ``M(q) a + h(q, v) = S^T tau + sum_c J_c(q)^T w_c``, is
linear in the parameters on the left, ``Y(q, v, a) theta``, but the contact wrenches ``w_c``
on the right are unknown unless force sensors measure them. Three ways to regress (each with
its own rows, chosen by `contact_equations`'s ``rows``):

* ``"all"``: every row, with the measured contact wrenches on the right-hand side;
* ``"base"``: the six base rows alone, ``Y_base theta = sum_c (J_c^T w_c)_base``; they hold
  without joint torques and without any joint friction model (Ayusawa, Venture and Nakamura,
  2014) and determine the total mass and the first moments;
* ``"projected"``: without force sensors, every row multiplied by the projector onto the null
  space of the active contacts' Jacobian, ``P = I - J_a^+ J_a``, which removes the unknown
  contact wrenches: ``P Y theta = P S^T tau`` (Khorshidi et al., ICRA 2025).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

import torch

from .._validation import as_tensor, check_finite
from ..dynamics import FloatingBaseModel, ParameterLayout
from ..physical import DEFAULT_PARAMETRIZATION, check, project
from ..stats import Moments
from ._prior import prior_options

__all__ = [
    "ROWS",
    "RowMoments",
    "consistent_floating",
    "contact_equations",
    "contact_moments",
    "row_moments",
]

ROWS = ("auto", "all", "base", "projected")


def _flags(contacts, names, batch, like) -> torch.Tensor:
    """``(B, n_contacts)`` 0/1 contact flags in ``names`` order."""
    cols = []
    for name in names:
        f = as_tensor(contacts[name], name=f"contact_{name}").to(like).reshape(-1)
        if f.shape[0] != batch:
            raise ValueError(f"contact_{name} has {f.shape[0]} samples, the state {batch}")
        check_finite(f, f"contact_{name}")
        if not bool(((f == 0) | (f == 1)).all()):
            raise ValueError(f"contact_{name} must hold 0 (no contact) or 1 (contact) only")
        cols.append(f)
    return torch.stack(cols, -1)


def _generalised_wrench(model, q, wrenches: Mapping[str, object], batch: int) -> torch.Tensor:
    """``sum_c J_c^T w_c``, ``(B, 6 + n)``, of measured wrenches in world axes."""
    names = list(wrenches)
    J = model.frame_jacobian(q, names)  # (B, k, 6, 6 + n)
    total = q.new_zeros(batch, 6 + model.n_dof)
    for k, name in enumerate(names):
        w = as_tensor(wrenches[name], name=f"wrench at {name}").to(q)
        if w.ndim != 2 or w.shape[0] != batch or w.shape[1] not in (3, 6):
            raise ValueError(
                f"the wrench at {name!r} must have shape ({batch}, 3) (a force, N) or "
                f"({batch}, 6) (force and moment, N and N m), got {tuple(w.shape)}"
            )
        check_finite(w, f"wrench at {name}")
        rows = J[:, k, : w.shape[1]]
        total = total + (rows.transpose(1, 2) @ w[..., None])[..., 0]
    return total


def contact_equations(
    model: FloatingBaseModel,
    q,
    v,
    a,
    tau,
    *,
    contacts: Mapping[str, object] | None = None,
    wrenches: Mapping[str, object] | None = None,
    flat: Collection[str] = (),
    rows: str = "auto",
) -> tuple[torch.Tensor, torch.Tensor]:
    """The regression rows ``Y theta = y`` of a floating-base robot's samples.

    Args:
        model: the robot.
        q: ``(B, 7 + n)`` base pose and joint positions (`FloatingBaseModel.regressor`).
        v: ``(B, 6 + n)`` base twist in base axes and joint velocities.
        a: ``(B, 6 + n)`` their time derivatives.
        tau: ``(B, n)`` joint torques, N m (N); unused by ``rows="base"`` (may be None there).
        contacts: frame name -> ``(B,)`` 0/1 flags: which frames touch the ground when
            (``"projected"``).
        wrenches: frame name -> ``(B, 3)`` measured force (N) or ``(B, 6)`` force and moment
            (N, N m, about the frame origin), in world axes (``"all"``, ``"base"``).
        flat: the contact frames that also transmit a moment (flat feet, a hand gripping, and a
            spherical foot whose frame is the sphere's centre: the ground pushes at its bottom,
            so the wrench about the centre has a moment, the radius times the tangential
            force): their projection removes six directions, a point contact's three.
        rows: ``"all"``, ``"base"``, ``"projected"`` (the module), or ``"auto"``: ``"all"``
            with wrenches, ``"projected"`` with contact flags only.

    Returns:
        ``(Y, y)``: ``(B, r, n_params)`` and ``(B, r)``, with ``r = 6`` for ``"base"`` and
        ``6 + n`` otherwise, in the inputs' dtype; stack them over samples for least squares.

    Raises:
        ValueError: on an unknown ``rows``, a choice the data cannot serve (``"all"`` or
            ``"base"`` without wrenches, ``"projected"`` without contacts), unknown frames,
            bad shapes or non-finite values, flags other than 0 and 1.
    """
    if rows not in ROWS:
        raise ValueError(f"rows must be one of {ROWS}, got {rows!r}")
    if rows == "auto":
        rows = "all" if wrenches else "projected"
    if rows in ("all", "base") and not wrenches:
        raise ValueError(
            f"rows={rows!r} needs the measured contact wrenches (force sensors); with contact "
            "flags only, use rows='projected'"
        )
    if rows == "projected" and not contacts:
        raise ValueError("rows='projected' needs contact flags (which frames touch when)")
    Y = model.regressor(q, v, a)
    if Y.ndim != 3:
        raise ValueError(f"q must have shape (B, {7 + model.n_dof}), got a {Y.ndim - 1}-d batch")
    B, n = Y.shape[0], model.n_dof
    q = as_tensor(q, name="q").to(Y)
    y = Y.new_zeros(B, 6 + n)
    if rows != "base":
        tau = as_tensor(tau, name="tau").to(Y)
        if tau.shape != (B, n):
            raise ValueError(f"tau must have shape ({B}, {n}), got {tuple(tau.shape)}")
        check_finite(tau, "tau")
        y[:, 6:] = tau
    if rows in ("all", "base"):
        y = y + _generalised_wrench(model, q, wrenches, B)
        return (Y[:, :6], y[:, :6]) if rows == "base" else (Y, y)
    names = list(contacts)
    unknown = set(flat) - set(names)
    if unknown:
        raise ValueError(f"flat names {sorted(unknown)}, which are not among the contacts")
    on = _flags(contacts, names, B, Y)  # (B, k)
    J = model.frame_jacobian(q, names)  # (B, k, 6, 6 + n)
    keep = torch.tensor([6 if name in flat else 3 for name in names], device=Y.device)
    mask = (torch.arange(6, device=Y.device) < keep[:, None]).to(Y)  # (k, 6)
    Ja = (J * (on[..., None] * mask)[..., None]).reshape(B, -1, 6 + n)
    P = torch.eye(6 + n, dtype=Y.dtype, device=Y.device) - torch.linalg.pinv(Ja) @ Ja
    return P @ Y, (P @ y[..., None])[..., 0]


class _Padded:
    """A floating-base model seen by the fixed-base tools (`project`, `check`,
    `prior_options`): the base body as one more body with joint terms that no data touch, so
    that every body has the same block of ``10 + n_terms`` parameters."""

    def __init__(self, model: FloatingBaseModel):
        self.model = model
        joints = model.joints.layout
        self.layout = ParameterLayout(
            (model.base_name, *joints.joint_names),
            joints.friction,
            (model.base_name, *joints.term_owners),
        )
        self.n_terms = joints.n_friction
        self.parameter_names = self.layout.parameter_names
        self.n_params = self.layout.n_params
        self.nominal_theta = self.pad(model.nominal_theta)

    def pad(self, theta: torch.Tensor) -> torch.Tensor:
        return torch.cat([theta[:10], theta.new_zeros(self.n_terms), theta[10:]])

    def unpad(self, theta: torch.Tensor) -> torch.Tensor:
        return torch.cat([theta[:10], theta[10 + self.n_terms :]])

    def pad_moments(self, m: Moments) -> Moments:
        k = self.n_terms
        index = torch.cat([torch.arange(10), torch.arange(10 + k, self.n_params)])
        xtx = m.xtx.new_zeros(self.n_params, self.n_params)
        xtx[index[:, None], index[None, :]] = m.xtx
        sum_x, xty = (x.new_zeros(self.n_params).index_copy(0, index, x) for x in (m.sum_x, m.xty))
        return Moments(m.n, sum_x, m.sum_y, xtx, xty, m.yty, m.n_rows)


class RowMoments:
    """The `Moments` of each row of a floating-base robot's equations (the base's six, then
    one per joint; after `contact_equations`), kept apart so that each row can be weighted
    and judged on its own.

    Attributes:
        rows: one `Moments` per row.
    """

    def __init__(self, rows: Sequence[Moments]) -> None:
        self.rows = list(rows)

    @classmethod
    def zeros(cls, n_rows: int, n_params: int) -> RowMoments:
        """Empty statistics of ``n_rows`` rows of ``n_params`` parameters."""
        return cls([Moments.zeros(n_params) for _ in range(n_rows)])

    def update(self, Y: torch.Tensor, y: torch.Tensor) -> RowMoments:
        """Add ``(B, r, n_params)`` rows and their ``(B, r)`` right-hand sides in place."""
        for r, m in enumerate(self.rows):
            m.update(Y[:, r], y[:, r])
        return self

    def __add__(self, other: RowMoments) -> RowMoments:
        return RowMoments([a + b for a, b in zip(self.rows, other.rows, strict=True)])

    @property
    def n_samples(self) -> int:
        """Samples seen."""
        return self.rows[0].n_rows

    def combined(self, weights: Sequence[float] | torch.Tensor | None = None) -> Moments:
        """All rows in one `Moments`, row ``r`` weighted by ``weights[r]`` (default 1)."""
        w = torch.ones(len(self.rows), dtype=torch.float64) if weights is None else weights
        w = torch.as_tensor(w, dtype=torch.float64)
        parts = [
            torch.stack([getattr(m, key) * float(wr) for m, wr in zip(self.rows, w, strict=True)])
            for key in ("n", "sum_x", "sum_y", "xtx", "xty", "yty")
        ]
        n_rows = sum(m.n_rows for m in self.rows)
        return Moments(*(p.sum(0) for p in parts), n_rows=n_rows)

    def rms(self, theta) -> torch.Tensor:
        """``(r,)`` each row's RMS residual ``y - Y theta`` (its unit: N, N m)."""
        theta = torch.as_tensor(theta, dtype=torch.float64)
        out = [m.rss(theta) / max(m.n_rows, 1) for m in self.rows]
        return torch.stack(out).clamp_min(0.0).sqrt()

    def target_rms(self) -> torch.Tensor:
        """``(r,)`` each row's RMS right-hand side (the residual of theta = 0)."""
        return torch.stack([(m.yty / max(m.n_rows, 1)).clamp_min(0.0).sqrt() for m in self.rows])


def row_moments(
    model: FloatingBaseModel,
    log,
    *,
    rows: str = "auto",
    flat: Collection[str] = (),
    chunk_size: int = 2048,
) -> RowMoments:
    """The `RowMoments` of a legged log's regression rows (`contact_equations`), streamed
    ``chunk_size`` samples at a time.

    Args:
        model: the robot.
        log: a `torchjfa.data.LeggedLog` with ``v`` and ``a`` (`torchjfa.data.prepare_legged`).
        rows: as `contact_equations`; the log's ``contact`` flags and ``wrench`` are passed
            (flags for ``"projected"``, wrenches otherwise).
        flat: as `contact_equations`.
        chunk_size: samples per chunk.

    Raises:
        ValueError: on a log without velocities or accelerations, or as `contact_equations`.
    """
    if log.v is None or log.a is None:
        raise ValueError("the log has no velocities or accelerations: prepare it first")
    out = None
    T = len(log.t)
    for s in range(0, T, chunk_size):
        part = slice(s, min(T, s + chunk_size))
        wrenches = {k: w[part] for k, w in log.wrench.items()} or None
        contacts = {k: c[part] for k, c in log.contact.items()} or None
        Y, y = contact_equations(
            model, log.q[part], log.v[part], log.a[part],
            None if log.tau is None else log.tau[part],
            contacts=contacts, wrenches=wrenches, flat=flat, rows=rows,
        )  # fmt: skip
        out = out or RowMoments.zeros(Y.shape[1], model.n_params)
        out.update(Y, y)
    if out is None:
        raise ValueError("the log has no samples")
    return out


def contact_moments(
    model: FloatingBaseModel,
    log,
    *,
    rows: str = "auto",
    flat: Collection[str] = (),
    chunk_size: int = 2048,
) -> Moments:
    """The `Moments` of a legged log's regression rows (`contact_equations`), for any
    estimator's ``fit_moments``: `row_moments` (the same arguments and errors) with every row
    weighted 1."""
    return row_moments(model, log, rows=rows, flat=flat, chunk_size=chunk_size).combined()


def consistent_floating(
    model: FloatingBaseModel,
    moments: Moments,
    theta_hat: torch.Tensor,
    *,
    prior_weight: float | None = 1.0,
    parametrization: str = DEFAULT_PARAMETRIZATION,
):
    """Physically consistent parameters of a floating-base robot closest to an unconstrained
    estimate in the data's metric (`torchjfa.physical.project` over every body, the base's
    included), pulled towards the description with ``prior_weight`` (in the units of
    `torchjfa.identification.Options.description_prior`; None: no prior).

    Args:
        model: the robot.
        moments: the rows' `Moments` (`contact_moments`).
        theta_hat: ``(n_params,)`` the unconstrained estimate.
        prior_weight: the description prior's weight, or None.
        parametrization: as `torchjfa.physical.project`.

    Returns:
        ``(theta, projection, report)``: ``(n_params,)`` float64 in the model's layout; the
        `torchjfa.physical.ProjectionResult` (in a layout that gives the base joint terms,
        unused and 0); and theta's `torchjfa.physical.ConsistencyReport`, one body per entry,
        the base first.
    """
    padded = _Padded(model)
    m = padded.pad_moments(moments)
    hat = padded.pad(torch.as_tensor(theta_hat, dtype=torch.float64))
    extra = {}
    if prior_weight is not None:
        extra = prior_options(padded, m, hat, float(prior_weight))
        if float(prior_weight) > 0:
            extra["ridge"] = 0.0
    result = project(hat, layout=padded.layout, moments=m, parametrization=parametrization, **extra)
    theta = result.theta.detach().to(torch.float64)
    return padded.unpad(theta), result, check(theta, padded.layout)
