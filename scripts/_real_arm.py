"""One real arm, one log: the default `torchjfa identify` against hand-tuned least squares.

The shared body of the single-log real-robot scripts (``real_lwr4.py``, ``real_tx40.py``): each
describes its robot with an `Arm` and hands it to `main`. What they run:

* the **last part**: the log split where ``1 - holdout`` of it (by time) has passed; every row
  identified on the part before (`torchjfa.identify`, what ``torchjfa identify`` runs; the
  part after is given as the validation log, so nothing the defaults choose sees it) and judged
  on the part after;
* **split points** (``--origins``): the same at several split times ``T``, each row identified
  on ``[0, T)`` alone and judged on the ``window_s`` seconds after ``T`` (from
  ``2 / eval_cutoff_hz`` after it, so that the filtered target holds no training torque).

A hand-picked cut-off whose filter's reach leaves the held-out part no samples is skipped
(``nan`` in the split-point table); ``--smoke`` runs a few seconds of the log with the
highest hand-picked cut-off alone: a check that the script runs, not a result.

Rows: the **defaults** (``torchjfa.identify(robot, train, Options(**arm.defaults))``: the plain
command, plus what the robot's README says must be given, such as a transmission file); the
**hand-tuned** reference (ordinary least squares, textbook Coulomb friction ``sign(qd)``, the
joint terms ``arm.hand_friction``, no description prior, at the best of ``arm.hand_cutoffs``
judged on the held-out part itself: an advantage the defaults do not get); the **description**
(the robot file's parameters with the damping and friction it states).

Every row is judged by ONE evaluation pipeline: the whole log prepared at ``eval_cutoff_hz``
(the same for every row, so that a row's own smoother target cannot win), the predicted
torques against the measured torque filtered by the same zero-phase filter: per-joint RMS, N m,
and its mean over the joints; the same against the unfiltered torque is printed beside it.
Where the robot's torque limits are known, also FloBaRoID's normalised error: the mean over the
joints of RMS / (2 x the limit) x 100, %.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import _benchmarks_page as page
import torch

import torchjfa
from torchjfa.data import JointLog, LogError, prepare, read_log, write_log
from torchjfa.identification import IdentificationWarning, load_model

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


@dataclasses.dataclass(frozen=True)
class Arm:
    """One robot and its log, and how the comparison treats them.

    Attributes:
        name: the script's name, also its section of the benchmarks page.
        title: the robot in words.
        folder: the data folder (the robot file and the log).
        log: the log's file name in ``folder``.
        robot: the robot file's name in ``folder``.
        defaults: `torchjfa.Options` keywords of the default command; a value may be a
            callable of the temporary folder (e.g. one that writes a transmission file there
            and returns its path).
        hand_friction: the hand-tuned reference's joint terms.
        hand_cutoffs: its cut-offs to pick from, Hz.
        eval_cutoff_hz: the one evaluation pipeline's cut-off, Hz.
        holdout: the share of the log (by time) held out by the last-part comparison.
        origins: the split points of ``--origins``, s from the log's start.
        window_s: the seconds judged after each split point.
        limits: the joints' torque limits, N m, for the normalised error (None: not printed).
        smoke_s: the seconds of the log a ``--smoke`` run uses.
    """

    name: str
    title: str
    folder: Path
    log: str
    robot: str
    defaults: dict
    hand_friction: tuple[str, ...]
    hand_cutoffs: tuple[float, ...]
    eval_cutoff_hz: float
    holdout: float
    origins: tuple[float, ...]
    window_s: float
    limits: tuple[float, ...] | None = None
    smoke_s: float = 8.0


def options(arm: Arm, tmp: Path, **changes) -> torchjfa.Options:
    """The defaults' `torchjfa.Options` (callables evaluated on ``tmp``), with ``changes``."""
    given = {k: (v(tmp) if callable(v) else v) for k, v in arm.defaults.items()}
    return torchjfa.Options(**{**given, **changes})


def hand_tuned(arm: Arm, tmp: Path, cutoff: float) -> torchjfa.Options:
    """The reference: OLS, textbook Coulomb friction, no prior, at ``cutoff``."""
    return options(
        arm,
        tmp,
        estimator="ols",
        friction=arm.hand_friction,
        cutoff=cutoff,
        coulomb_velocity=0.0,
        description_prior=None,
        jackknife=0,
        bias_correction=0,
    )


def evaluation(arm: Arm, log: JointLog, t_split: float, t_end: float = math.inf) -> dict:
    """The one evaluation pipeline on the samples from ``t_split + 2 / eval_cutoff_hz`` to
    ``t_end``: q, qd, qdd and the filtered (``tau``) and unfiltered (``tau_raw``) torque."""
    filtered = prepare(log, cutoff_hz=arm.eval_cutoff_hz, period_s=None)
    raw = prepare(log, cutoff_hz=arm.eval_cutoff_hz, period_s=None, filter_torque=False)
    keep = (filtered.t >= t_split + 2.0 / arm.eval_cutoff_hz) & (filtered.t < t_end)
    return {
        "q": filtered.q[keep],
        "qd": filtered.qd[keep],
        "qdd": filtered.qdd[keep],
        "tau": filtered.tau[keep],
        "tau_raw": raw.tau[keep],
    }


def rms(model, theta, ev) -> tuple[torch.Tensor, torch.Tensor]:
    """``(n_dof,)`` RMS of the predicted torque against the filtered and the unfiltered
    torque, N m."""
    pred = model.regressor(ev["q"], ev["qd"], ev["qdd"]) @ theta
    return (
        (pred - ev["tau"]).pow(2).mean(0).sqrt(),
        (pred - ev["tau_raw"]).pow(2).mean(0).sqrt(),
    )


def normalised(arm: Arm, r: torch.Tensor) -> float:
    """FloBaRoID's normalised error of per-joint RMS ``r``, %; NaN without limits."""
    if arm.limits is None:
        return math.nan
    lim = torch.as_tensor(arm.limits, dtype=r.dtype)
    return float((r / (2.0 * lim)).mean() * 100.0)


def split(log: JointLog, t_split: float, tmp: Path) -> tuple[Path, Path]:
    """The log before ``t_split`` and from it on as CSV files: ``(train, held-out)``."""
    n = int(torch.searchsorted(log.t, torch.tensor(t_split, dtype=log.t.dtype)))
    train, held = tmp / "train.csv", tmp / "heldout.csv"
    write_log(log.select(slice(0, n)), train)
    write_log(log.select(slice(n, log.n_samples)), held)
    return train, held


def identify(arm: Arm, files: tuple[Path, Path], opts: torchjfa.Options):
    """`torchjfa.identify` of one row on ``files`` (train, held-out): ``(ident, seconds)``."""
    started = time.perf_counter()
    with warnings.catch_warnings():  # the rows' warnings are in their reports
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(arm.folder / arm.robot, files[0], opts, validation_log=files[1])
    return ident, time.perf_counter() - started


def description(arm: Arm, tmp: Path):
    """The robot file's model (the defaults' drive train, if any) and its description theta."""
    opts = options(arm, tmp)
    model = load_model(arm.folder / arm.robot, transmission=opts.transmission)
    return model, model.description_theta


def _load(arm: Arm, smoke: bool, out) -> JointLog | None:
    path = arm.folder / arm.log
    if not path.is_file():
        print(f"no {arm.title} log at {path}: nothing to do", file=out)
        return None
    log = read_log(path)
    if smoke:
        log = log.select(log.t < log.t[0] + arm.smoke_s)
    return log


def last_part(arm: Arm, *, smoke: bool = False, out=sys.stdout) -> dict | None:
    """The rows on the last ``holdout`` of the log; the numbers, or None without the log."""
    log = _load(arm, smoke, out)
    if log is None:
        return None
    t_split = float(log.t[0] + (1.0 - arm.holdout) * (log.t[-1] - log.t[0]))
    ev = evaluation(arm, log, t_split)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = split(log, t_split, tmp)
        ident, seconds = identify(arm, files, options(arm, tmp))
        rows["defaults"] = (*rms(ident.model, ident.theta, ev), ident.data.cutoff_hz)
        cutoffs = arm.hand_cutoffs[-1:] if smoke else arm.hand_cutoffs
        hand = {}
        for c in cutoffs:
            try:
                h, _ = identify(arm, files, hand_tuned(arm, tmp, c))
            except LogError:  # the filter's reach leaves this cut-off no held-out part
                continue
            hand[c] = (*rms(h.model, h.theta, ev), c)
        best = min(hand, key=lambda c: float(hand[c][0].mean()))
        rows[f"hand-tuned ({best:g} Hz)"] = hand[best]
        model, theta = description(arm, tmp)
        rows["description"] = (*rms(model, theta, ev), math.nan)
    print(
        f"{arm.title}: identified on the first {1 - arm.holdout:.0%} of the log "
        f"({t_split - float(log.t[0]):.2f} s), judged on the rest ({ev['q'].shape[0]} samples) "
        f"against the torque filtered at {arm.eval_cutoff_hz:g} Hz (and unfiltered)"
        + ("; SMOKE: not a result" if smoke else ""),
        file=out,
    )
    print(
        "hand-tuned cut-offs tried: "
        + ", ".join(f"{c:g} Hz {float(v[0].mean()):.4g}" for c, v in hand.items()),
        file=out,
    )
    names = list(ident.model.joint_names)
    _table(arm, names, rows, out)
    d, h = float(rows["defaults"][0].mean()), float(hand[best][0].mean())
    consistent = bool(ident.report.consistency.ok)
    print(
        f"defaults / hand-tuned mean RMS: {d / h:.3f} ({d:.4g} against {h:.4g} N m); "
        f"physically consistent: {consistent}; the defaults chose {rows['defaults'][2]:g} Hz "
        f"and the joint terms {', '.join(ident.model.friction)}; identify took {seconds:.1f} s",
        file=out,
    )
    for w in ident.warnings:
        print(f"warning of the defaults: {w}", file=out)
    return {"ratio": d / h, "consistent": consistent, "defaults": d, "hand": h,
            "normalised": normalised(arm, rows["defaults"][0])}  # fmt: skip


def _table(arm: Arm, names, rows, out) -> None:
    short = [n[-8:] for n in names]
    norm = "" if arm.limits is None else f"{'norm %':>8}"
    print(f"{'row':<24}" + "".join(f"{s:>9}" for s in short) + f"{'mean':>9}{'raw':>9}" + norm,
          file=out)  # fmt: skip
    for label, (filt, raw, _) in rows.items():
        cells = "".join(f"{float(x):9.4g}" for x in filt)
        tail = "" if arm.limits is None else f"{normalised(arm, filt):8.4f}"
        print(f"{label:<24}{cells}{float(filt.mean()):9.4g}{float(raw.mean()):9.4g}{tail}",
              file=out)  # fmt: skip


def split_points(arm: Arm, *, out=sys.stdout) -> list[dict] | None:
    """The defaults against the hand-tuned reference at ``arm.origins``; one dict per split."""
    log = _load(arm, False, out)
    if log is None:
        return None
    print(
        f"split points: each row identified on [0, T) alone, judged on the {arm.window_s:g} s "
        f"from T + {2.0 / arm.eval_cutoff_hz:g} s on against the torque filtered at "
        f"{arm.eval_cutoff_hz:g} Hz; mean RMS over the joints, N m",
        file=out,
    )
    head = "".join(f"{'OLS ' + format(c, 'g'):>9}" for c in arm.hand_cutoffs)
    print(f"{'T, s':>6}{'defaults':>16}{head}{'ratio':>8}", file=out)
    results = []
    for t in arm.origins:
        t_split = float(log.t[0]) + t
        t_end = t_split + 2.0 / arm.eval_cutoff_hz + arm.window_s
        if t_end > float(log.t[-1]) + 0.5 * arm.window_s:
            print(f"{t:6.2f}: no window of the log here, skipped", file=out)
            continue
        ev = evaluation(arm, log, t_split, t_end)
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            files = split(log, t_split, tmp)
            ident, _ = identify(arm, files, options(arm, tmp))
            d = float(rms(ident.model, ident.theta, ev)[0].mean())
            hand = {}
            for c in arm.hand_cutoffs:
                try:
                    h, _ = identify(arm, files, hand_tuned(arm, tmp, c))
                except LogError:  # the filter's reach leaves this cut-off no held-out part
                    hand[c] = math.nan
                    continue
                hand[c] = float(rms(h.model, h.theta, ev)[0].mean())
        best = min(v for v in hand.values() if not math.isnan(v))
        results.append({"t": t, "defaults": d, "cutoff_hz": ident.data.cutoff_hz, "hand": hand})
        print(
            f"{t:6.2f}{d:9.4g} ({ident.data.cutoff_hz:4.3g})"
            + "".join(f"{v:9.4g}" for v in hand.values())
            + f"{d / best:8.3f}",
            file=out,
            flush=True,
        )
    if results:
        d = statistics.fmean(r["defaults"] for r in results)
        best = statistics.fmean(
            min(v for v in r["hand"].values() if not math.isnan(v)) for r in results
        )
        print(
            f"mean over the {len(results)} splits: defaults {d:.4g}, hand-tuned at the best "
            f"cut-off of each window {best:.4g} N m: {d / best:.3f}x",
            file=out,
        )
    return results


def main(arm: Arm, argv=None, doc: str | None = None) -> int:
    """The command line of a single-log real-robot script."""
    p = argparse.ArgumentParser(description=(doc or __doc__).splitlines()[0])
    p.add_argument("--smoke", action="store_true", help="a few seconds, one cut-off (a check)")
    p.add_argument(
        "--origins", action="store_true", help="the defaults against OLS at several split points"
    )
    args = page.add_option(p).parse_args(argv)
    name = f"{arm.name}-origins" if args.origins else arm.name
    with page.recording(name, arm.name, args.write_docs, argv, smoke=args.smoke):
        if args.origins:
            split_points(arm, out=sys.stdout)
        else:
            last_part(arm, smoke=args.smoke, out=sys.stdout)
    return 0
