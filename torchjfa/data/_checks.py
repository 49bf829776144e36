"""Checks that a log can identify anything at all, before any fitting.

A log can be well formed (`read_log` accepts it) and still be meaningless for identification:
a gap of seconds that resampling would bridge with an invented spline, a robot that stands
still, positions in degrees, velocities in deg/s, columns scrambled by a wrong reshape.
Unchecked, each of these ends in a confident report with absurd numbers (held-out nMSE from 6
to 1e24) and exit status 0.
`check_log` finds them and says what to do, one line each; a `LogProblem` that is ``fatal``
means the result would be meaningless (`torchjfa identify` stops with exit status 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._log import JointLog

__all__ = ["LogProblem", "check_log", "velocity_ratios"]

GAP_STEPS = 20  # a step this many times the median ...
GAP_MIN_S = 0.05  # ... and at least this long is a gap, not jitter
STILL_RAD = 1e-3  # a joint whose 1-99 % position range is below this does not move
ROUGH = 0.2  # RMS sample-to-sample change over the position range: not a smooth motion
LIMIT_MARGIN_RAD = 0.05  # positions this far beyond a limit (plus 5 % of the range) leave it
# measured velocities against the positions' change: over windows of VELOCITY_WINDOW_S, the
# least-squares ratio of the integral of qd to the change of q (1 when qd is dq/dt in rad/s)
VELOCITY_WINDOW_S = 0.05
DEG_RATIO = 180.0 / math.pi  # qd in deg/s with q in rad ...
DEG_TOLERANCE = 0.2  # ... within 20 % of it: fatal
SCALE_FACTOR = 2.0  # a ratio beyond [1/2, 2] (or negative): a warning naming the joint
MIN_CORRELATION = 0.5  # |correlation| below it: qd does not follow q's change (a warning)


@dataclass(frozen=True)
class LogProblem:
    """One thing wrong with a log.

    Attributes:
        message: one line for the person who recorded the log: what, where, what to do.
        fatal: True when identifying from the log would give a meaningless result.
    """

    message: str
    fatal: bool


def _gaps(log: JointLog) -> list[LogProblem]:
    t = log.t.numpy()
    dt = np.diff(t)
    h = float(np.median(dt))
    big = np.flatnonzero(dt > max(GAP_STEPS * h, GAP_MIN_S))
    if not big.size:
        return []
    i = int(big[np.argmax(dt[big])])
    return [
        LogProblem(
            f"{log.source}: time jumps by {dt[i]:.3g} s at t = {t[i]:.6g} s (row {i + 1}; "
            f"{big.size} gap(s) longer than {max(GAP_STEPS * h, GAP_MIN_S):.3g} s, the median "
            f"step is {h:.3g} s): resampling would bridge it with invented motion; split the "
            "log at the gap and identify from the parts (several logs), or record it again",
            fatal=True,
        )
    ]


def _ranges(q: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(q, [1.0, 99.0], axis=0)
    return hi - lo


def _motion(log: JointLog) -> list[LogProblem]:
    q = log.q.numpy()
    width = _ranges(q)
    still = [j for j, w in zip(log.joint_names, width, strict=True) if w < STILL_RAD]
    if len(still) == log.n_dof:
        return [
            LogProblem(
                f"{log.source}: the robot does not move (every joint's positions stay within "
                f"{STILL_RAD:g} rad): a log of a standing robot determines no inertial "
                "parameter; record an excitation trajectory (torchjfa excite)",
                fatal=True,
            )
        ]
    out = []
    if still:
        out.append(
            LogProblem(
                f"{log.source}: joint(s) {still} barely move (1-99 % range below {STILL_RAD:g} "
                "rad): the parameters they alone excite are not determined by this log",
                fatal=False,
            )
        )
    moving = width >= STILL_RAD
    step = np.sqrt(np.mean(np.diff(q, axis=0) ** 2, axis=0))
    rough = [
        (j, s / w)
        for j, s, w, m in zip(log.joint_names, step, width, moving, strict=True)
        if m and s > ROUGH * w
    ]
    if rough:
        j, r = max(rough, key=lambda x: x[1])
        out.append(
            LogProblem(
                f"{log.source}: the positions are not a smooth motion ({len(rough)} joint(s); "
                f"{j} changes from one sample to the next by {r:.0%} of its range, RMS): were "
                "the columns mixed up (an (n_samples, n_dof) array read as (n_dof, n_samples)) "
                "or is the time column wrong?",
                fatal=True,
            )
        )
    return out


def velocity_ratios(log: JointLog) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, how the measured velocity compares with the positions' change.

    Over windows of `VELOCITY_WINDOW_S` (at least one sample step) the change of ``q`` is
    compared with the integral of ``qd`` (trapezoids): the least-squares ratio of the integral
    to the change is 1 for a ``qd`` that is ``dq/dt`` in the positions' unit per second, ~57.3
    for deg/s with radians. Integrating, unlike differentiating ``q``, neither amplifies the
    position noise nor loses the fast part of the motion.

    Returns:
        ``(n_dof,)`` ratios and ``(n_dof,)`` correlations of the two; NaN for a joint that
        does not move (1-99 % range below `STILL_RAD`) or a log without ``qd``.
    """
    ratio = np.full(log.n_dof, np.nan)
    corr = np.full(log.n_dof, np.nan)
    if log.qd is None or log.n_samples < 3:
        return ratio, corr
    t, q, qd = log.t.numpy(), log.q.numpy(), log.qd.numpy()
    dt = np.diff(t)
    w = int(np.clip(round(VELOCITY_WINDOW_S / float(np.median(dt))), 1, (log.n_samples - 1) // 2))
    integral = np.concatenate(
        [np.zeros((1, log.n_dof)), np.cumsum(0.5 * (qd[1:] + qd[:-1]) * dt[:, None], axis=0)]
    )
    dq = q[w:] - q[:-w]
    di = integral[w:] - integral[:-w]
    for j in np.flatnonzero(_ranges(q) >= STILL_RAD):
        a, b = dq[:, j], di[:, j]
        aa, bb = float(a @ a), float(b @ b)
        if aa > 0 and bb > 0:
            ratio[j] = float(a @ b) / aa
            corr[j] = float(a @ b) / math.sqrt(aa * bb)
    return ratio, corr


def _velocities(log: JointLog) -> list[LogProblem]:
    ratio, corr = velocity_ratios(log)
    names = np.array(log.joint_names, dtype=object)
    known = np.isfinite(ratio)
    follows = known & (np.abs(corr) >= MIN_CORRELATION)
    deg = follows & (np.abs(ratio / DEG_RATIO - 1.0) <= DEG_TOLERANCE)
    off = follows & ~deg & ((ratio < 1.0 / SCALE_FACTOR) | (ratio > SCALE_FACTOR))
    loose = known & ~follows  # qd unrelated to q's change
    out = []

    def joints(mask) -> list[str]:
        return [str(n) for n in names[mask]]

    def listed(mask) -> str:
        return ", ".join(f"{n} {r:.3g}" for n, r in zip(names[mask], ratio[mask], strict=True))

    if deg.any():
        out.append(
            LogProblem(
                f"{log.source}: the velocities of joint(s) {joints(deg)} look like deg/s "
                f"while the positions are in rad (qd is {listed(deg)} times the positions' "
                f"change per second, about 180/pi = {DEG_RATIO:.1f}): convert the qd columns "
                "to rad/s (multiply by pi/180), or leave them out to differentiate q",
                fatal=True,
            )
        )
    if off.any():
        hint = ""
        if np.all(np.abs(ratio[off] * DEG_RATIO - 1.0) <= DEG_TOLERANCE):
            hint = " (about pi/180: are the positions in degrees?)"
        elif off.sum() == follows.sum() > 1 and np.ptp(np.log(np.abs(ratio[off]))) < 0.2:
            hint = " (the same factor for every joint: is the time column's unit right?)"
        out.append(
            LogProblem(
                f"{log.source}: the velocities of joint(s) {joints(off)} disagree with the "
                f"positions' change per second by a factor ({listed(off)}; 1 expected){hint}: "
                "check the qd columns' unit (rad/s), sign and joint order, or leave them out "
                "to differentiate q",
                fatal=False,
            )
        )
    if loose.any():
        shown = ", ".join(f"{n} {c:.2f}" for n, c in zip(names[loose], corr[loose], strict=True))
        out.append(
            LogProblem(
                f"{log.source}: the velocities of joint(s) {joints(loose)} do not follow "
                f"the positions' change (correlation {shown}; near 1 expected): are the qd "
                "columns those of these joints, and in step with q?",
                fatal=False,
            )
        )
    return out


def _limits(log: JointLog, limits) -> list[LogProblem]:
    lim = np.asarray(limits, dtype=np.float64)
    if lim.shape != (log.n_dof, 2):
        raise ValueError(f"limits must be (n_dof, 2) = ({log.n_dof}, 2), got {lim.shape}")
    q = log.q.numpy()
    lo_q, hi_q = q.min(0), q.max(0)
    known = np.isfinite(lim).all(1) & (lim[:, 1] > lim[:, 0])
    margin = LIMIT_MARGIN_RAD + 0.05 * (lim[:, 1] - lim[:, 0])
    over = known & ((lo_q < lim[:, 0] - margin) | (hi_q > lim[:, 1] + margin))
    if not over.any():
        return []
    rad = np.deg2rad(q)
    fits = known & (rad.min(0) >= lim[:, 0] - margin) & (rad.max(0) <= lim[:, 1] + margin)
    worst = int(np.argmax(np.where(over, np.maximum(lim[:, 0] - lo_q, hi_q - lim[:, 1]), -1)))
    name = log.joint_names[worst]
    where = (
        f"{name} spans [{lo_q[worst]:.4g}, {hi_q[worst]:.4g}] where its limits are "
        f"[{lim[worst, 0]:.4g}, {lim[worst, 1]:.4g}] rad"
    )
    scale = np.abs(lim).max(1)
    far = np.abs(q).max(0)[over] > 5.0 * scale[over]  # degrees are 57x radians
    if fits[known].all() and far.all() and (hi_q - lo_q)[over].max() > math.pi:
        return [
            LogProblem(
                f"{log.source}: the positions look like degrees ({where}; in radians every "
                "joint would lie inside its limits): convert the log's positions (and "
                "velocities) to radians",
                fatal=True,
            )
        ]
    bad = [log.joint_names[j] for j in np.flatnonzero(over)]
    return [
        LogProblem(
            f"{log.source}: joint(s) {bad} leave the description's limits ({where}): does the "
            "log use the description's zero, sign and units for every joint?",
            fatal=False,
        )
    ]


def check_log(log: JointLog, *, limits=None) -> list[LogProblem]:
    """What makes ``log`` unfit for identification, most serious first.

    Args:
        log: a `JointLog` as `read_log` returns it (before `prepare`).
        limits: optional ``(n_dof, 2)`` lower and upper position limits of the log's joints
            (rad or m; non-finite or empty intervals are skipped), e.g. from the robot
            description (``RigidBodyModel.chain.get_joint_limits()``).

    Returns:
        A list of `LogProblem` (empty when nothing is found): gaps in time longer than
        ``max(20 median steps, 0.05 s)``, joints that do not move, positions that are not a
        smooth motion, positions outside the limits (or in degrees), velocities in deg/s
        with positions in rad (fatal: qd within 20 % of 180/pi times the positions' change per
        second, see `velocity_ratios`), velocities that disagree with the positions' change
        by more than a factor 2 or do not follow it (warnings).
    """
    problems = _gaps(log) + _motion(log) + _velocities(log)
    if limits is not None:
        problems += _limits(log, limits)
    return sorted(problems, key=lambda p: not p.fatal)
