"""A torque channel that contradicts the robot: a flipped sign (the joint's axis or the motor's
direction), a swapped column, wrong units, found from the data before the fit trusts them.

Per joint, the measured torque is regressed on the description's predicted torque (its
inertials, no joint terms) and the joint's own friction columns (viscous ``qd``, Coulomb
``tanh(qd / v)``, an offset): on a channel that measures what the description predicts, the
description's torque enters with a positive scale and the friction with positive
coefficients (up to the description's errors, on real robots a scale of 0.6 to 1.6 and more
where the description's torque is small). A channel whose scale and friction are all negative
is measured with the opposite sign convention.
"""

from __future__ import annotations

import torch

from ..data import JointLog
from ..dynamics import RigidBodyModel
from ..report import predicted_torques

__all__ = ["channel_warnings"]

#: the Coulomb column's smoothing velocity in this check, rad/s
_COULOMB_V = 0.02


def channel_warnings(model: RigidBodyModel, log: JointLog) -> list[str]:
    """One warning per prepared log (q, qd, qdd, tau) naming the joints whose torque runs
    against the description's prediction and their own friction (see the module); none when
    the description has no inertials."""
    nominal = model.nominal_theta
    if not bool((nominal != 0).any()) or log.qdd is None:
        return []
    log = log.reorder(model.joint_names)
    pred = predicted_torques(model, nominal, log.q, log.qd, log.qdd, log.tau)
    flipped = []
    for j, name in enumerate(model.joint_names):
        qd = log.qd[:, j]
        X = torch.stack([pred[:, j], qd, torch.tanh(qd / _COULOMB_V), torch.ones_like(qd)], 1)
        if float(pred[:, j].std()) <= 1e-9 * float(pred.abs().max()):
            continue  # the description predicts nothing here
        a, b, c, _ = torch.linalg.lstsq(X, log.tau[:, j : j + 1]).solution.flatten().tolist()
        if a < 0 and b < 0 and c < 0:
            flipped.append(f"{name} (scale {a:.2g}, viscous {b:.2g}, Coulomb {c:.2g})")
    if not flipped:
        return []
    return [
        f"{log.source}: the torque of joint(s) {', '.join(flipped)} runs against the "
        "description's prediction and against its own friction (a least-squares fit of the "
        "measured torque on the description's torque and the joint's friction gives all three "
        "negative): check its sign convention (the joint's axis, the motor's direction), its "
        "column and its units. The joint weights (weighting='residual') keep it from pulling "
        "the other joints' fit; its own parameters are not to be trusted"
    ]
