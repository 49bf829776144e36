"""The default `torchjfa identify` on a real Franka Panda log, against hand-tuned least squares.

    python scripts/real_panda.py            # the whole log (about a minute)
    python scripts/real_panda.py --smoke    # a few seconds of it, two rows (a check, no figures)
    python scripts/real_panda.py --origins  # the same comparison at five split points (1 minute)
    python scripts/real_panda.py --write-docs   # also into docs/benchmarks.md

The log is `../shared/data/panda_gaz2019` (its README: a real Panda excitation, uneven 1 kHz,
measured q, qd and link-side torques; not shipped with the package). Without it the script says
so and stops (exit 0).

The last 20 % of the log (by time) is held out. Every row is identified by `torchjfa.identify`
with its `torchjfa.Options` (what the `torchjfa identify` command runs; each row prints the
options it changes) on the first 80 % alone (the held-out part is given as the
validation log, so the fit uses the whole 80 % and nothing it chooses sees the held-out part),
and every row is
judged by ONE evaluation pipeline: the whole log prepared at one cut-off (``EVAL_CUTOFF_HZ``, the
same for all rows, so that a row's own smoother target cannot win), the held-out samples from
``2 / EVAL_CUTOFF_HZ`` s after the split on (so that the filtered target holds under 0.5 % of
training torques), the per-joint RMS of the predicted minus the filtered measured torque;
the same against the unfiltered torque is printed beside it. Rows:

* defaults: ``torchjfa.Options()``, i.e. ``torchjfa identify panda_arm train.csv`` and nothing
  else;
* the same without the description prior (``description_prior=None``; the default is
  ``"auto"``);
* Bayesian JFA: the best of a few configurations (judged on the held-out part: an advantage
  the defaults do not get);
* OLS, viscous + Coulomb + offset friction (textbook Coulomb, ``sign(qd)``, no description
  prior), at the best of a few hand-picked cut-offs (judged on the held-out part too: the
  hand-tuned reference the defaults are judged against);
* the defaults (smoothed Coulomb term ``tanh(qd / v_c)``, v_c chosen at each cut-off, the
  description prior) at the same hand-picked cut-offs: what the hand-picked cut-off adds to
  the defaults;
* the description: the URDF's parameters (no friction).

Then the identified link masses of the defaults against the description's, with the band
[0.3x, 3x], and how much of the held-out motion lies inside the training part's range of every
joint (the rest is extrapolation in configuration, where the gravity terms of parameters the
training part hardly excites decide the error).

``--origins``: one split judges the rows on one window of motion. With ``--origins`` the
script repeats the comparison of the defaults and the hand-tuned OLS rows at several split
points ``T`` (``ORIGINS``, the last the 80 % split): each row identified on ``[0, T)`` alone,
judged by the same pipeline on the ``ORIGIN_WINDOW_S`` seconds after ``T + 2 / EVAL_CUTOFF_HZ``;
printed per split: the defaults (with the cut-off they chose), OLS at each hand-picked cut-off,
the best of those on that window, the share of the window inside the training range, and the
means over the splits.
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
from _real_arm import split as _split

import torchjfa
from torchjfa.data import JointLog, prepare
from torchjfa.identification import IdentificationWarning, load_model

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "panda_gaz2019"
ROBOT = "panda_arm"
JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
HOLDOUT = 0.2
EVAL_CUTOFF_HZ = 10.0  # fixed before any row was run; none of the rows' choices
FRICTION = "viscous,coulomb,offset"
FRICTION_TERMS = tuple(FRICTION.split(","))
HAND_CUTOFFS = (5.0, 8.0, 12.0, 20.0)
JFA_CONFIGS = (
    {"estimator": "bayes-jfa"},
    {"estimator": "bayes-jfa", "estimator_options": {"ard": "output"}},
    {"estimator": "bayes-jfa", "weighting": "none"},
)
MASS_BAND = (0.3, 3.0)
SMOKE_SECONDS = 10.0
ORIGINS = (6.0, 7.5, 9.0, 10.5, None)  # s from the log's start; None: the 80 % split
ORIGIN_WINDOW_S = 2.8


def load_panda(folder: str | Path = DATA) -> JointLog:
    """The log in ``folder`` (time.txt, positions.txt, velocity.txt, torques.txt) as a JointLog."""
    import numpy as np

    folder = Path(folder)
    t = np.loadtxt(folder / "time.txt")
    n = t.shape[0]

    def matrix(name):
        return np.loadtxt(folder / name).reshape(n, len(JOINTS))

    return JointLog(
        t=t,
        q=matrix("positions.txt"),
        qd=matrix("velocity.txt"),
        tau=matrix("torques.txt"),
        joint_names=JOINTS,
        source=str(folder),
    )


def _identify(train_csv: Path, valid_csv: Path, options: torchjfa.Options):
    """`torchjfa.identify` of one row; ``(Identification, seconds)``."""
    started = time.perf_counter()
    with warnings.catch_warnings():  # the rows' warnings are in their reports
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(ROBOT, train_csv, options, validation_log=valid_csv)
    return ident, time.perf_counter() - started


def _changes(options: torchjfa.Options) -> str:
    """The options a row changes from the defaults, e.g. ``estimator='ols', cutoff=8.0``."""
    default = torchjfa.Options()
    changed = [
        f"{f.name}={getattr(options, f.name)!r}"
        for f in dataclasses.fields(options)
        if getattr(options, f.name) != getattr(default, f.name)
    ]
    return ", ".join(changed) or "(the defaults)"


def _evaluation(log: JointLog, t_split: float, t_end: float = math.inf) -> dict[str, torch.Tensor]:
    """The one evaluation pipeline: the whole log at EVAL_CUTOFF_HZ, held-out samples only
    (from ``t_split + 2 / EVAL_CUTOFF_HZ`` to ``t_end``), and ``inside``: the share of them
    whose every joint lies inside the range the training part (before ``t_split``) covers."""
    filtered = prepare(log, cutoff_hz=EVAL_CUTOFF_HZ, period_s=None)
    raw = prepare(log, cutoff_hz=EVAL_CUTOFF_HZ, period_s=None, filter_torque=False)
    keep = (filtered.t >= t_split + 2.0 / EVAL_CUTOFF_HZ) & (filtered.t < t_end)
    seen = log.q[log.t < t_split]
    q = filtered.q[keep]
    inside = ((q >= seen.min(0).values) & (q <= seen.max(0).values)).all(1)
    return {
        "q": q,
        "qd": filtered.qd[keep],
        "qdd": filtered.qdd[keep],
        "tau": filtered.tau[keep],
        "tau_raw": raw.tau[keep],
        "inside": inside.to(torch.float64).mean(),
    }


def _hand_tuned(base: torchjfa.Options, cutoff: float) -> torchjfa.Options:
    """The reference: OLS, textbook Coulomb friction (sign(qd)), no prior, at ``cutoff``."""
    return base.replace(
        estimator="ols",
        friction=FRICTION_TERMS,
        cutoff=cutoff,
        coulomb_velocity=0.0,
        description_prior=None,
    )


def _rms(model, theta, ev) -> tuple[torch.Tensor, torch.Tensor]:
    pred = model.regressor(ev["q"], ev["qd"], ev["qdd"]) @ theta
    return (
        (pred - ev["tau"]).pow(2).mean(0).sqrt(),
        (pred - ev["tau_raw"]).pow(2).mean(0).sqrt(),
    )


def _masses(model, theta) -> list[float]:
    names = list(model.parameter_names)
    return [float(theta[names.index(f"{j}.m")]) for j in model.joint_names]


def run(folder: str | Path = DATA, *, smoke: bool = False, out=sys.stdout) -> dict | None:
    """Identify every row, print the table; returns the numbers (None without the log).

    Args:
        folder: the log's folder.
        smoke: the first SMOKE_SECONDS of the log, the defaults (with ``--jackknife 0``) and one OLS row
            only: a check that the script runs, not a result.
        out: where the table goes.
    """
    folder = Path(folder)
    if not (folder / "torques.txt").is_file():
        print(f"no Panda log in {folder} (see scripts/real_panda.py): nothing to do", file=out)
        return None
    log = load_panda(folder)
    if smoke:
        log = log.select(slice(0, int(torch.searchsorted(log.t, log.t[0] + SMOKE_SECONDS))))
    t_split = _split_time(log)
    ev = _evaluation(log, t_split)
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        train_csv, valid_csv = _split(log, t_split, Path(tmp))

        def row(label, options):
            ident, seconds = _identify(train_csv, valid_csv, options)
            filt, raw = _rms(ident.model, ident.theta, ev)
            return {
                "label": label,
                "cutoff_hz": ident.data.cutoff_hz,
                "seconds": seconds,
                "options": _changes(options),
                "rms": filt,
                "rms_raw": raw,
                "model": ident.model,
                "theta": ident.theta,
                "warnings": ident.warnings,
            }

        base = torchjfa.Options(jackknife=0) if smoke else torchjfa.Options()
        rows["defaults"] = row("defaults", base)
        if not smoke:
            rows["no-prior"] = row(
                "defaults, no description prior", base.replace(description_prior=None)
            )
            jfa = [row("Bayesian JFA", base.replace(**c)) for c in JFA_CONFIGS]
            rows["bayes-jfa"] = min(jfa, key=lambda r: float(r["rms"].mean()))
            tried = ", ".join(f"{r['options']} {float(r['rms'].mean()):.4f}" for r in jfa)
        cutoffs = HAND_CUTOFFS[1:2] if smoke else HAND_CUTOFFS
        ols = [row(f"OLS {FRICTION}, {c:g} Hz", _hand_tuned(base, c)) for c in cutoffs]
        rows["ols"] = min(ols, key=lambda r: float(r["rms"].mean()))
        if not smoke:  # the same with the defaults' smoothed Coulomb term (v_c chosen at c)
            smooth = [
                row(
                    f"defaults at {c:g} Hz",
                    base.replace(estimator="ols", friction=FRICTION_TERMS, cutoff=c),
                )
                for c in cutoffs
            ]
            rows["ols-smooth"] = min(smooth, key=lambda r: float(r["rms"].mean()))
    nominal = load_model(ROBOT, ())
    filt, raw = _rms(nominal, nominal.nominal_theta, ev)
    rows["description"] = {
        "label": "description (URDF)",
        "options": "",
        "rms": filt,
        "rms_raw": raw,
        "model": nominal,
        "theta": nominal.nominal_theta,
    }
    _print(rows, ev, out, smoke=smoke, ols_all=ols)
    if not smoke:
        print(f"Bayesian JFA configurations tried: {tried}", file=out)
    return rows


def _split_time(log: JointLog) -> float:
    """The time of the default split: the last HOLDOUT of the log (by time) held out."""
    return float(log.t[0] + (1.0 - HOLDOUT) * (log.t[-1] - log.t[0]))


def origins(
    folder: str | Path = DATA,
    *,
    times=ORIGINS,
    window_s: float = ORIGIN_WINDOW_S,
    cutoffs=HAND_CUTOFFS,
    out=sys.stdout,
) -> list[dict] | None:
    """The defaults against hand-tuned OLS at several split points (module docstring).

    Args:
        folder: the log's folder.
        times: the split points, s from the log's start (None: the 80 % split).
        window_s: the seconds judged after each split (from ``2 / EVAL_CUTOFF_HZ`` on).
        cutoffs: the hand-picked cut-offs of the OLS rows, Hz.
        out: where the table goes.

    Returns:
        One dict per split: ``t`` (s), ``inside`` (share of the window inside the training
        range), ``defaults`` and ``cutoff_hz`` (the defaults' mean RMS, N m, and the cut-off they
        chose), ``ols`` (hand-picked cut-off -> mean RMS, N m); None without the log.
    """
    folder = Path(folder)
    if not (folder / "torques.txt").is_file():
        print(f"no Panda log in {folder} (see scripts/real_panda.py): nothing to do", file=out)
        return None
    log = load_panda(folder)
    base = torchjfa.Options()
    results = []
    print(
        f"split points: each row identified on [0, T) alone, judged on the {window_s:g} s "
        f"from T + {2.0 / EVAL_CUTOFF_HZ:g} s on against the torque filtered at "
        f"{EVAL_CUTOFF_HZ:g} Hz; mean RMS over the joints, N m",
        file=out,
    )
    head = " ".join(f"{'OLS ' + format(c, 'g'):>8}" for c in cutoffs)
    print(f"{'T, s':>6} {'inside':>6} {'defaults':>15} {head} {'best OLS':>8} {'vs':>7}", file=out)
    for t in times:
        t_split = _split_time(log) if t is None else float(log.t[0]) + float(t)
        t_end = t_split + 2.0 / EVAL_CUTOFF_HZ + window_s
        if not float(log.t[0]) < t_split < t_end <= float(log.t[-1]) + window_s / 2:
            print(f"{t_split - float(log.t[0]):6.2f}: no window of the log here, skipped", file=out)
            continue
        ev = _evaluation(log, t_split, t_end)
        with tempfile.TemporaryDirectory() as tmp:
            files = _split(log, t_split, Path(tmp))
            d, cutoff = _mean_rms(files, ev, base)
            ols = {c: _mean_rms(files, ev, _hand_tuned(base, c))[0] for c in cutoffs}
        best = min(ols.values())
        results.append(
            {
                "t": t_split - float(log.t[0]),
                "inside": float(ev["inside"]),
                "defaults": d,
                "cutoff_hz": cutoff,
                "ols": ols,
            }
        )
        print(
            f"{t_split - float(log.t[0]):6.2f} {float(ev['inside']):6.0%} "
            f"{d:8.4f} ({cutoff:4.3g}) "
            + " ".join(f"{v:8.4f}" for v in ols.values())
            + f" {best:8.4f} {100 * (1 - d / best):+6.1f}%",
            file=out,
            flush=True,
        )
    if not results:
        return results
    mean = statistics.fmean
    d = mean([r["defaults"] for r in results])
    fixed = {c: mean([r["ols"][c] for r in results]) for c in cutoffs}
    best = mean([min(r["ols"].values()) for r in results])
    c_fixed = min(fixed, key=fixed.get)
    print(
        f"mean over the {len(results)} splits: defaults {d:.4f}; OLS at the best cut-off of "
        f"each window {best:.4f} (defaults {100 * (1 - d / best):+.1f} %); OLS at the best "
        f"single cut-off for all windows ({c_fixed:g} Hz) {fixed[c_fixed]:.4f} (defaults "
        f"{100 * (1 - d / fixed[c_fixed]):+.1f} %); the defaults below the best OLS of the "
        f"window at {sum(r['defaults'] < min(r['ols'].values()) for r in results)} of "
        f"{len(results)} splits",
        file=out,
    )
    return results


def _mean_rms(files: tuple[Path, Path], ev, options: torchjfa.Options) -> tuple[float, float]:
    """One row on ``files`` (train, held-out CSV): its mean held-out RMS on ``ev``, N m, and the
    cut-off it used, Hz."""
    ident, _ = _identify(*files, options)
    return float(_rms(ident.model, ident.theta, ev)[0].mean()), ident.data.cutoff_hz


def _smoothing(model) -> str:
    v = model.coulomb_velocity
    return f", Coulomb tanh(qd / {v:g} rad/s)" if v else ", Coulomb sign(qd)"


def _print(rows, ev, out, *, smoke, ols_all) -> None:
    n = ev["q"].shape[0]
    print(
        f"held-out: the last {HOLDOUT:.0%} of the log, {n} samples; every row judged against "
        f"the torque filtered at {EVAL_CUTOFF_HZ:g} Hz (and, in brackets, the unfiltered torque)"
        + (f"; SMOKE: {SMOKE_SECONDS:g} s of the log, not a result" if smoke else ""),
        file=out,
    )
    head = f"{'row':<36} " + " ".join(f"{'j' + str(i + 1):>6}" for i in range(7))
    print(head + f" {'mean':>7} {'(raw)':>8}", file=out)
    for r in rows.values():
        print(
            f"{r['label'][:36]:<36} "
            + " ".join(f"{float(v):6.3f}" for v in r["rms"])
            + f" {float(r['rms'].mean()):7.4f} ({float(r['rms_raw'].mean()):.4f})",
            file=out,
        )
    print(
        "OLS cut-offs tried: "
        + ", ".join(f"{r['label'].split(', ')[-1]} {float(r['rms'].mean()):.4f}" for r in ols_all),
        file=out,
    )
    for key in ("defaults", "no-prior", "bayes-jfa", "ols", "ols-smooth"):
        if key in rows:
            r = rows[key]
            print(
                f"{key}: {r['options']}; cut-off {r['cutoff_hz']:g} Hz"
                + _smoothing(r["model"])
                + f"; the command took {r['seconds']:.1f} s",
                file=out,
            )
    d, o = float(rows["defaults"]["rms"].mean()), float(rows["ols"]["rms"].mean())
    print(
        f"defaults vs hand-tuned OLS: {d:.4f} vs {o:.4f} N m, {100 * (1 - d / o):+.1f} % "
        f"(the goal: at least +10 %): {'met' if d <= 0.9 * o else 'NOT met'}",
        file=out,
    )
    print(
        f"held-out motion inside the training range of every joint: {float(ev['inside']):.0%} "
        "of the samples (the rest extrapolates in configuration)",
        file=out,
    )
    ident, desc = rows["defaults"], rows["description"]
    got, ref = _masses(ident["model"], ident["theta"]), _masses(desc["model"], desc["theta"])
    print("link masses, kg: identified (defaults) / description, ratio", file=out)
    for j, a, b in zip(JOINTS, got, ref, strict=True):
        ratio = a / b if b > 0 else math.inf
        flag = "" if MASS_BAND[0] <= ratio <= MASS_BAND[1] else "  outside [0.3x, 3x]"
        print(f"  {j:<13} {a:8.3f} / {b:6.3f}  {ratio:6.2f}x{flag}", file=out)


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=str(DATA), help="the log's folder")
    p.add_argument("--smoke", action="store_true", help="a few seconds, two rows")
    p.add_argument(
        "--origins", action="store_true", help="the defaults against OLS at several split points"
    )
    return page.add_option(p)


def main(argv=None):
    a = parser().parse_args(argv)
    name = "real_panda-origins" if a.origins else "real_panda"
    with page.recording(name, "real_panda", a.write_docs, argv, smoke=a.smoke):
        if a.origins:
            return origins(a.data, out=sys.stdout)
        return run(a.data, smoke=a.smoke, out=sys.stdout)


if __name__ == "__main__":
    main()
