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

from collections.abc import Collection, Mapping

import torch

from .._validation import as_tensor, check_finite
from ..dynamics import FloatingBaseModel

__all__ = ["contact_equations", "ROWS"]

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
