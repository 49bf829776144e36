"""The verdict at the top of ``report.md``: is the identified model better than the description
on held-out data, is it physically consistent, what the data leave undetermined, the warnings,
and what to do next.

`make_verdict` reads an `IdentificationReport` (its attributes only: this module imports
nothing from `torchjfa.report`); `next_steps` applies the rules below, most urgent first:

1. the measured torque is a multiple of the description's prediction far from 1, or runs
   against it on a joint: units (or motor currents without drive gains) or a flipped sign;
2. the held-out error is worse than the description's (or than the torques' mean); then
   consecutive joints whose torques a motor turning both would explain (a coupled drive); then
   joints whose torque neither the model nor the unconstrained estimate predicts better than
   its mean while the other joints are predicted (a channel that does not follow the motion);
3. the estimator stopped at its iteration cap;
4. the parameters are not (fully) physically consistent;
5. joints the model explains badly, or whose parameters the log excites too little;
6. warnings no rule above covers;
7. last, whenever no rule 1, 2 or a failed consistency (no description written) stands against
   using the model: load it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import torch

__all__ = ["BETTER", "UNEXPLAINED", "UNIT_RANGE", "Verdict", "make_verdict", "next_steps"]

#: RMS error ratios (the description's over the identified model's) above this read "better",
#: below its inverse "worse", between "about as good"
BETTER = 1.1
#: a joint whose held-out nMSE is above this: the model explains less than half its variance
UNEXPLAINED = 0.5
#: the measured torque over the description's prediction (least squares, median over joints):
#: outside this range the torques are in another unit (or are currents without drive gains)
UNIT_RANGE = (1.0 / 3.0, 3.0)
#: a joint whose measured torque correlates with the description's prediction below this runs
#: against it (a flipped sign)
SIGN_CORRELATION = -0.5
#: at most this many next steps
MAX_STEPS = 3
#: words that make a warning more urgent than the rest (the lower the rank, the more urgent)
_URGENT = (
    ("did not converge", 0),
    ("runs against", 0),
    ("coupled drive", 0),
    ("look like deg", 0),
    ("disagree with the positions", 0),
    ("do not follow the positions", 0),
    ("barely move", 1),
    ("leave the description's limits", 1),
    ("beyond the identification data", 1),
)


@dataclass(frozen=True)
class Verdict:
    """What the verdict says, as numbers and words (`make_verdict`).

    Attributes:
        rms: the identified model's held-out RMS torque error, the quadratic mean over the
            joints (N m; N for prismatic joints).
        rms_description: the same for the description's parameters, or None without them.
        mean_nmse: the identified model's held-out nMSE, the mean over the joints.
        better, same, worse: the joints where the identified model's RMS error is below, about
            (within a factor `BETTER`) or above the description's.
        consistent, consistent_weakly: `ConsistencyReport.ok` and ``weakly_ok``.
        counts: parameters per status (`torchjfa.physical.BaseParameters.counts`), or None
            when the data excite nothing.
        n_params: the number of parameters.
        prior_weight: the description prior's weight, or None.
        description_terms: the joint terms the description states and its prediction
            includes (``"damping and friction"``, ...), or ``""`` for its inertials alone.
        warnings: every warning, most urgent first.
        next_steps: what to do next, most urgent first (`next_steps`).
    """

    rms: float
    rms_description: float | None
    mean_nmse: float
    better: tuple[str, ...]
    same: tuple[str, ...]
    worse: tuple[str, ...]
    consistent: bool
    consistent_weakly: bool
    counts: dict[str, int] | None
    n_params: int
    prior_weight: float | None
    warnings: tuple[str, ...]
    next_steps: tuple[str, ...]
    description_terms: str = ""

    @property
    def ratio(self) -> float | None:
        """The description's RMS error over the identified model's (> 1: better), or None."""
        if self.rms_description is None or not self.rms > 0:
            return None
        return self.rms_description / self.rms

    @property
    def rating(self) -> str:
        """``"better"``, ``"about as good"``, ``"worse"`` (than the description) or ``"no
        description"``."""
        return _rating(self.ratio)

    @property
    def n_determined(self) -> int:
        """Parameters the data determine alone."""
        return 0 if self.counts is None else int(self.counts["determined"])

    @property
    def n_not_determined(self) -> int:
        """Parameters the data do not determine alone (combination, poorly or not excited)."""
        return self.n_params - self.n_determined

    def summary(self) -> dict[str, object]:
        """The verdict as JSON-ready values."""
        return {
            "rms": self.rms,
            "rms_description": self.rms_description,
            "ratio_to_description": self.ratio,
            "rating": self.rating,
            "mean_nmse": self.mean_nmse,
            "joints_better": list(self.better),
            "joints_about_as_good": list(self.same),
            "joints_worse": list(self.worse),
            "consistent": self.consistent,
            "n_params": self.n_params,
            "n_determined": self.n_determined,
            "n_not_determined": self.n_not_determined,
            "counts": self.counts,
            "n_warnings": len(self.warnings),
            "next_steps": list(self.next_steps),
        }


def _rating(ratio: float | None) -> str:
    if ratio is None or not math.isfinite(ratio):
        return "no description"
    if ratio >= BETTER:
        return "better"
    if ratio > 1.0 / BETTER:
        return "about as good"
    return "worse"


def quadratic_mean(rms: torch.Tensor) -> float:
    """``sqrt(mean(rms^2))`` over the joints: the RMS over every held-out torque sample."""
    return float(torch.as_tensor(rms, dtype=torch.float64).pow(2).mean().sqrt())


def make_verdict(report, model_path: str = "model.npz") -> Verdict:
    """The verdict of an `IdentificationReport`; ``model_path``: where the load step points."""
    fits, joints = report.fits, list(report.model.joint_names)
    ident, desc = fits["identified"], fits.get("description")
    groups: dict[str, list[str]] = {"better": [], "about as good": [], "worse": []}
    if desc is not None:
        for j, name in enumerate(joints):
            a, b = float(ident.rms[j]), float(desc.rms[j])
            groups.setdefault("better" if not a > 0 else _rating(b / a), []).append(name)
    warnings = ranked_warnings(report.warnings())
    base = report.base
    v = Verdict(
        rms=quadratic_mean(ident.rms),
        rms_description=None if desc is None else quadratic_mean(desc.rms),
        mean_nmse=ident.mean_nmse,
        better=tuple(groups["better"]),
        same=tuple(groups["about as good"]),
        worse=tuple(groups["worse"]),
        consistent=report.consistency.ok,
        consistent_weakly=report.consistency.weakly_ok,
        counts=None if base is None else base.counts(),
        n_params=report.model.n_params,
        prior_weight=report.result.prior_weight,
        warnings=tuple(warnings),
        next_steps=(),
        description_terms=stated_terms(report.model) if desc is not None else "",
    )
    return replace(v, next_steps=tuple(next_steps(report, v, model_path)))


def stated_terms(model) -> str:
    """The joint terms the description states that its prediction includes, in words
    (``"damping and friction"``), or ``""``."""
    _, terms = model.layout.split(model.description_theta)
    names = {"viscous": "damping", "coulomb": "friction", "armature": "armature"}
    found = [names[k] for j, k in enumerate(model.friction)
             if k in names and bool((terms[:, j] != 0).any())]  # fmt: skip
    return " and ".join([", ".join(found[:-1]), found[-1]] if len(found) > 2 else found)


def ranked_warnings(warnings) -> list[str]:
    """``warnings`` most urgent first (a flipped sign, wrong units, no convergence; then too
    little motion and extrapolation; then the rest), each group in its given order."""

    def rank(w: str) -> int:
        return min((r for word, r in _URGENT if word in w), default=2)

    return sorted(warnings, key=rank)


def short_warning(text: str, limit: int = 150) -> str:
    """A warning on one short line: the logs' paths (``<path>: ``) dropped, cut at its first
    colon or semicolon after the opening words (what follows says why and what to do), at
    most ``limit`` characters."""
    text = _PATH.sub("", text)
    cuts = [i for i in (text.find(": ", 30), text.find("; ", 30)) if i > 0]
    if cuts:
        text = text[: min(cuts)]
    if len(text) > limit:
        text = text[: limit - 3].rsplit(" ", 1)[0] + "..."
    return text


#: a log's path before a colon: with a slash, or a file name with an extension
_PATH = re.compile(r"(?:\S*/\S*|\S+\.[A-Za-z]\w{0,7}): ")


# ------------------------------------------------------------------------------ the rules
def next_steps(report, verdict: Verdict, model_path: str = "model.npz") -> list[str]:
    """What to do next, most urgent first, at most `MAX_STEPS` (see the module's rules)."""
    blocking = [_units_step(report), _worse_step(verdict)]
    steps = [
        *blocking,
        _coupled_step(verdict.warnings),
        _channel_step(report),
        _convergence_step(report.result.estimator),
        _consistency_step(report),
        _excite_step(report, verdict),
        _warnings_step(verdict.warnings),
    ]
    steps = [s for s in steps if s]
    if not any(blocking) and verdict.consistent_weakly:
        steps = steps[: MAX_STEPS - 1]
        steps.append(
            f"load the model: `from torchjfa.io import load_identified; model = "
            f'load_identified("{model_path}")` (an `nn.Module`: joint torques from q, qd, qdd)'
        )
    return steps[:MAX_STEPS]


def torque_scales(report) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Per joint, the least-squares scale of the measured held-out torque on the description's
    prediction and their correlation, ``((n_dof,), (n_dof,))``; NaN where the description
    predicts no change; None without the description's prediction."""
    desc = report.fits.get("description")
    if desc is None:
        return None
    tau = torch.as_tensor(report.validation.tau, dtype=torch.float64)
    pred = desc.predicted.to(torch.float64)
    tc, pc = tau - tau.mean(0), pred - pred.mean(0)
    pp, tt = pc.pow(2).sum(0), tc.pow(2).sum(0)
    silent = pp <= (1e-12 * float(pp.max())) if float(pp.max()) > 0 else pp >= 0
    scale = torch.where(silent, torch.nan, (tc * pc).sum(0) / pp.clamp_min(1e-300))
    corr = torch.where(silent, torch.nan, (tc * pc).sum(0) / (pp * tt).sqrt().clamp_min(1e-300))
    return scale, corr


def _units_step(report) -> str | None:
    """Rule 1: the torques a multiple of the description's prediction far from 1 (units,
    currents), or a joint whose torque runs against it (sign)."""
    found = torque_scales(report)
    if found is None:
        return None
    scale, corr = found
    joints = report.model.joint_names
    flipped = [joints[j] for j in range(len(joints)) if float(corr[j]) < SIGN_CORRELATION]
    if flipped:
        return (
            f"the measured torque of {', '.join(flipped)} runs against the description's "
            "prediction (negative correlation on the held-out data): check the sign of "
            "those torque columns (the joint's axis, the motor's direction) and identify again"
        )
    follows = corr > -SIGN_CORRELATION
    if not bool(follows.any()):
        return None
    s = float(scale[follows].median())
    if UNIT_RANGE[0] <= s <= UNIT_RANGE[1]:
        return None
    return (
        f"the measured torques are about {s:.3g} times the description's prediction: if the "
        "log holds motor currents, give the drive gains (`--drive-gains G1,G2,...` in N m/A); "
        "otherwise convert the torques to N m (N)"
    )


def _worse_step(v: Verdict) -> str | None:
    """Rule 2: worse than the description, or than the held-out torques' mean."""
    if v.mean_nmse >= 1.0 or not math.isfinite(v.mean_nmse):
        return (
            "the model predicts the held-out torques no better than their mean: check the "
            "torque columns' units and sign and the joint order, or record a longer, richer "
            "excitation"
        )
    if v.rating == "worse":
        return (
            "the held-out error is worse than the description's: check the units and sign of "
            "the torques and the joint order (the warnings); do not use this model"
        )
    return None


#: the joints a coupled-drive warning names (`torchjfa.data.CoupledDrive.describe`)
_COUPLED = re.compile(r"the torques of (\S+) and (\S+) follow each other's acceleration")


def _coupled_step(warnings) -> str | None:
    """Rule 2b: consecutive joints whose torques a motor turning both would explain."""
    pairs = [m.groups() for w in warnings if (m := _COUPLED.search(w))]
    if not pairs:
        return None
    named = "; ".join(f"{a} and {b}" for a, b in pairs)
    return (
        f"{named}: their torques follow each other's motion as one motor turning both would "
        "(a coupled drive the description lacks; the evidence in the warnings): write the drive "
        "train to a file (motor velocity = ratio @ joint velocity, a row with two entries for "
        "that motor) and identify again with `--transmission FILE`"
    )


def _channel_step(report) -> str | None:
    """Rule 2c: joints whose held-out torque neither the identified model nor the
    unconstrained estimate predicts better than its mean (nMSE of 1 or more)."""
    fits = report.fits
    if "unconstrained" not in fits:
        return None
    ident, free = fits["identified"].nmse, fits["unconstrained"].nmse
    joints = report.model.joint_names
    bad = [j for j in range(len(joints)) if float(ident[j]) >= 1.0 and float(free[j]) >= 1.0]
    if not bad or len(bad) == len(joints):  # every joint: rule 2 speaks of the whole model
        return None
    named = ", ".join(
        f"{joints[j]} (nMSE {float(ident[j]):.3g}, unconstrained {float(free[j]):.3g})" for j in bad
    )
    return (
        f"the rigid-body model with its joint terms predicts the held-out torque of {named} no "
        "better than its mean, although it predicts the other joints: that channel does not "
        "follow the robot's motion; check its sign, an offset that drifts, the sensor and "
        "its column"
    )


def _convergence_step(est) -> str | None:
    """Rule 3: the estimator stopped at its iteration cap."""
    if getattr(est, "converged_", True):
        return None
    return (
        f"{type(est).__name__} did not converge: raise `--max-iter`, or compare with "
        "`--estimator ols`"
    )


def _consistency_step(report) -> str | None:
    """Rule 4: not physically consistent (no description file written), or only in the sense
    of mass and inertia (a simulator may reject the triangle inequalities)."""
    c = report.consistency
    if c.ok:
        return None
    bad = [j for j, ok in zip(report.model.joint_names, c.body_ok.tolist(), strict=True) if not ok]
    if report.result.projection is None:
        how = "run with the projection (leave out `--no-project`)"
    else:
        how = "identify with `--parametrization log-cholesky`"
    what = "violate the triangle inequalities" if c.weakly_ok else "are not physical"
    return f"the bodies of {', '.join(bad)} {what}: {how}"


def _excite_step(report, v: Verdict) -> str | None:
    """Rule 5: joints the model explains badly (held-out nMSE above `UNEXPLAINED`), predicts
    worse than the description, or whose parameters the log leaves to the noise (poorly
    excited)."""
    joints = list(report.model.joint_names)
    nmse = report.fits["identified"].nmse
    bad = {joints[j] for j in range(len(joints)) if not float(nmse[j]) <= UNEXPLAINED}
    poor = set()
    if report.base is not None:
        for name, status in zip(report.base.names, report.base.status, strict=True):
            if status == "poorly excited":
                poor.add(name.rsplit(".", 1)[0])
    worse = set(v.worse)
    named = [j for j in joints if j in bad | poor | worse] + sorted(poor - set(joints))
    if not named:
        return None
    why = []
    if bad:
        why.append("the model explains less than half of their held-out torque")
    if worse - bad:
        why.append("the description predicts them better")
    if poor:
        why.append("the log leaves some of their parameters to the noise")
    robot = report.settings.get("robot") or str(report.model.source_path or "ROBOT")
    return (
        f"excite {', '.join(named)} more ({', or '.join(why)}): design a trajectory "
        f"with `torchjfa excite {robot} --out traj`, record it, and identify from both logs"
    )


def _warnings_step(warnings) -> str | None:
    """Rule 6: read the warnings."""
    if not warnings:
        return None
    if len(warnings) == 1:
        return 'read the warning (section "Warnings") and act on it'
    return f'read the {len(warnings)} warnings (section "Warnings") and act on each'
