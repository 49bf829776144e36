"""The default `torchjfa identify` on a real UR10e campaign (motor currents), against hand-tuned
least squares.

    python scripts/real_ur10e.py            # all 15 identification logs without payload
    python scripts/real_ur10e.py --smoke    # three logs, a check
    python scripts/real_ur10e.py --payload  # the known payloads of the loaded runs
    python scripts/real_ur10e.py --write-docs   # also into docs/benchmarks.md

The logs are `../shared/data/ur10e_mamedov2020` (its README: a UR10e in velocity control, about
94 Hz with uneven steps, measured q and qd, motor currents ``i_<joint>`` in A, the drive gains
``DRIVE_GAINS`` in N m/A that its authors estimated; not shipped with the package). Without
them the script says so and stops (exit 0).

Every identification log without a payload is used. Each is split where 80 % of its motion
(from its first to its last moving sample, `torchjfa.data.motion_span`) has passed; the first
part of every log identifies, the rest of every log is held out. Rows:

* defaults: ``torchjfa.identify(robot.urdf, first_parts, Options(drive_gains=DRIVE_GAINS),
  validation_log=held_parts)``: ``torchjfa identify robot.urdf LOG... --drive-gains ...``
  with nothing else (the held-out parts are given as validation logs, so nothing the defaults
  choose sees them);
* hand-tuned: Pinocchio's joint-torque regressor with viscous, Coulomb (``sign(qd)``) and
  offset friction per joint, ordinary least squares on the first parts filtered (zero-phase
  Butterworth, order 4) at the best of ``HAND_CUTOFFS`` (judged on the held-out parts: an
  advantage the defaults do not get); nothing physically consistent about it;
* the description: the URDF's inertial parameters, no friction.

Every row is judged by ONE evaluation pipeline: the held-out parts, their rest at the ends
dropped, prepared at ``EVAL_CUTOFF_HZ`` (the same for every row; `torchjfa.data.prepare`) for
q, qd and qdd, and the predicted torques compared with the measured torque (drive gain times
current) filtered by the same zero-phase filter (so that a row's own smoother target cannot
win, and the currents' ripple, which no row can predict, does not swamp the differences):
per-joint RMS, N m; the mean RMS against the unfiltered torque is printed beside it. The goal:
the defaults' mean RMS at most ``GOAL_RATIO`` times the hand-tuned reference's, with
physically consistent parameters.

``--payload``: the robot identified with the defaults from all 15 logs, then each loaded run
with a documented mass (``PAYLOADS``: 2.602 kg and 2.805 kg on ``ee_link``) through
`torchjfa.identification.identify_payload`, against the identified robot alone and together
with its unloaded twin; printed: the mass found against the known one, the centre of mass, and
the loaded run's held-out torque RMS without and with the payload.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import _benchmarks_page as page
import numpy as np
import torch
from scipy import signal

import torchjfa
from torchjfa.data import JointLog, motion_span, prepare, read_log
from torchjfa.identification import IdentificationWarning, measured_torque
from torchjfa.report import predicted_torques

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "ur10e_mamedov2020"
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
          "wrist_2_joint", "wrist_3_joint")  # fmt: skip
#: the authors' drive gains, N m/A (the dataset's README)
DRIVE_GAINS = (10.0000, 10.6956, 8.4566, 9.0029, 9.4800, 10.1232)
HOLDOUT = 0.2
#: the one evaluation preparation, Hz; the authors filter qd at about 7 Hz (the README)
EVAL_CUTOFF_HZ = 7.0
HAND_CUTOFFS = (3.0, 5.0, 7.0, 10.0)
GOAL_RATIO = 0.9
SMOKE_LOGS = 3
#: (loaded run, its unloaded twin, the payload's mass in kg), from the dataset's README
PAYLOADS = (
    ("ident_payload_ur-20_01_13-load_2600.csv", "ident_ur-19_12_23_free.csv", 2.602),
    ("ident_payload_ur-20_02_19_14harm50secLoad.csv", "ident_ur-20_02_19_14harm50sec.csv", 2.805),
)


def identification_logs(folder: Path = DATA) -> list[Path]:
    """The identification logs without a payload (``ident_ur-*.csv``)."""
    return sorted(folder.glob("ident_ur-*.csv"))


def split(log: JointLog) -> tuple[JointLog, JointLog]:
    """The log before and after 80 % of its motion."""
    span = motion_span(log)
    t0, t1 = float(log.t[span.start]), float(log.t[span.stop - 1])
    t_split = t0 + (1.0 - HOLDOUT) * (t1 - t0)
    head = log.select(log.t < t_split)
    tail = log.select(log.t >= t_split)
    return head, tail


def evaluation_data(tails: list[JointLog]) -> list[dict[str, torch.Tensor]]:
    """The held-out parts as every row sees them: rest dropped, prepared at EVAL_CUTOFF_HZ,
    the target the measured torque."""
    out = []
    for raw in tails:
        span = motion_span(raw)
        raw = raw.select(slice(0, min(raw.n_samples, span.stop + int(4.0 / EVAL_CUTOFF_HZ * 94))))
        data = prepare(raw, cutoff_hz=EVAL_CUTOFF_HZ, period_s=None)
        out.append(
            {"q": data.q, "qd": data.qd, "qdd": data.qdd, "tau": data.tau,
             "raw": measured_torque(raw, data.t)}
        )  # fmt: skip
    return out


# ------------------------------------------------------------------------------ hand-tuned
class HandTuned:
    """Pinocchio's regressor, viscous + Coulomb + offset friction, ordinary least squares."""

    def __init__(self, urdf: Path) -> None:
        import pinocchio as pin

        self.pin = pin
        self.model = pin.buildModelFromUrdf(str(urdf))
        self.data = self.model.createData()
        names = list(self.model.names)[1:]
        if names != list(JOINTS):
            raise SystemExit(f"Pinocchio reads the joints {names}, expected {JOINTS}")
        self.theta = None

    def regressor(self, q, qd, qdd) -> np.ndarray:
        """``(n * 6, 60 + 18)`` rows, joint-major per sample."""
        q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
        n, d = q.shape
        rb = np.stack(
            [
                self.pin.computeJointTorqueRegressor(self.model, self.data, q[i], qd[i], qdd[i])
                for i in range(n)
            ]
        )  # (n, d, 60)
        fr = np.zeros((n, d, 3 * d))
        for j in range(d):
            fr[:, j, 3 * j] = qd[:, j]
            fr[:, j, 3 * j + 1] = np.sign(qd[:, j])
            fr[:, j, 3 * j + 2] = 1.0
        return np.concatenate([rb, fr], axis=2).reshape(n * d, -1)

    def fit(self, heads: list[JointLog], cutoff: float) -> None:
        rows, taus = [], []
        for log in heads:
            t = log.t.numpy()
            rate = 1.0 / float(np.mean(np.diff(t)))
            b, a = signal.butter(4, cutoff, fs=rate)
            qd = signal.filtfilt(b, a, log.qd.numpy(), axis=0)
            qdd = np.gradient(qd, t, axis=0)
            tau = signal.filtfilt(b, a, log.tau.numpy(), axis=0)
            span = motion_span(log)
            edge = int(4.0 / cutoff * rate)
            keep = slice(max(edge, span.start), min(len(t) - edge, span.stop))
            rows.append(self.regressor(log.q.numpy()[keep], qd[keep], qdd[keep]))
            taus.append(tau[keep].reshape(-1))
        self.theta = np.linalg.lstsq(np.concatenate(rows), np.concatenate(taus), rcond=None)[0]

    def predict(self, ev: dict) -> torch.Tensor:
        y = self.regressor(ev["q"], ev["qd"], ev["qdd"]) @ self.theta
        return torch.from_numpy(y.reshape(ev["q"].shape))


def rms(preds: list[torch.Tensor], evals: list[dict], target: str = "tau") -> torch.Tensor:
    """``(n_dof,)`` RMS over all held-out samples against ``target`` (``"tau"``: filtered at
    EVAL_CUTOFF_HZ, ``"raw"``: unfiltered), N m."""
    err = torch.cat([p - e[target] for p, e in zip(preds, evals, strict=True)])
    return err.pow(2).mean(0).sqrt()


def run(folder: Path = DATA, *, smoke: bool = False, out=sys.stdout) -> dict | None:
    paths = identification_logs(folder)
    if not paths:
        print(f"no UR10e logs in {folder}; nothing to do", file=out)
        return None
    if smoke:
        paths = paths[:SMOKE_LOGS]
    urdf = folder / "robot.urdf"
    gains = dict(zip(JOINTS, DRIVE_GAINS, strict=True))
    logs = [read_log(p, drive_gains=gains).reorder(JOINTS) for p in paths]
    heads, tails = zip(*(split(log) for log in logs), strict=True)
    evals = evaluation_data(list(tails))
    print(
        f"{len(logs)} logs, {sum(h.duration for h in heads):.0f} s to identify from, "
        f"{sum(t.duration for t in tails):.0f} s held out; judged at {EVAL_CUTOFF_HZ:g} Hz "
        "against the measured torque (gain x current)",
        file=out,
    )
    rows, preds = {}, {}
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(
            urdf,
            list(heads),
            torchjfa.Options(drive_gains=DRIVE_GAINS),
            validation_log=list(tails),
        )
    seconds = time.perf_counter() - started
    model = ident.model
    for name, theta in (("defaults", ident.theta), ("description", model.nominal_theta)):
        preds[name] = [
            predicted_torques(model, theta, e["q"], e["qd"], e["qdd"], e["tau"]) for e in evals
        ]
    hand = HandTuned(urdf)
    best = None
    for cutoff in HAND_CUTOFFS:
        hand.fit(list(heads), cutoff)
        p = [hand.predict(e) for e in evals]
        r = rms(p, evals)
        print(f"  hand-tuned at {cutoff:g} Hz: mean RMS {float(r.mean()):.4g} N m", file=out)
        if best is None or float(r.mean()) < float(best[1].mean()):
            best = (cutoff, r, p)
    preds[f"hand-tuned ({best[0]:g} Hz)"] = best[2]
    rows = {name: rms(p, evals) for name, p in preds.items()}
    print(
        f"{'row':<24}" + "".join(f"{j[:11]:>12}" for j in JOINTS) + f"{'mean':>10}"
        f"{'unfiltered':>12}",
        file=out,
    )
    for name, r in rows.items():
        cells = "".join(f"{float(x):>12.4g}" for x in r)
        raw = float(rms(preds[name], evals, "raw").mean())
        print(f"{name:<24}{cells}{float(r.mean()):>10.4g}{raw:>12.4g}", file=out)
    ratio = float(rows["defaults"].mean()) / float(best[1].mean())
    consistent = bool(ident.report.consistency.ok)
    print(
        f"defaults / hand-tuned mean RMS: {ratio:.3f} (goal <= {GOAL_RATIO}); physically "
        f"consistent: {consistent}; identify took {seconds:.1f} s "
        f"(cut-off {ident.data.cutoff_hz:g} Hz; joint terms {', '.join(ident.model.friction)})",
        file=out,
    )
    if ident.data.joint_terms_how:
        print(f"armature: {ident.data.joint_terms_how}", file=out)
    return {
        "ratio": ratio,
        "consistent": consistent,
        "seconds": seconds,
        "rows": {k: [float(x) for x in v] for k, v in rows.items()},
        "warnings": ident.warnings,
        "logs": ident.report.settings["logs"],
    }


def payloads(folder: Path = DATA, *, out=sys.stdout) -> list[dict] | None:
    """The known payloads (``PAYLOADS``) identified two ways; one dict per run and way."""
    import tempfile

    from torchjfa.identification import identify_payload

    paths = identification_logs(folder)
    if not paths:
        print(f"no UR10e logs in {folder}; nothing to do", file=out)
        return None
    options = torchjfa.Options(drive_gains=DRIVE_GAINS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(folder / "robot.urdf", paths, options)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        model = ident.write(tmp, plots=False)["model"]
        for loaded, free, mass in PAYLOADS:
            for how, unloaded in (("robot", None), ("pair", folder / free)):
                p = identify_payload(
                    model, folder / loaded, link="ee_link", unloaded=unloaded, options=options
                )
                rows.append({"log": loaded, "how": how, "known": mass, "mass": p.mass,
                             "std": float(p.std[0]), "com": p.com.tolist(),
                             "rms_without": float(p.rms_without.mean()),
                             "rms_with": float(p.rms_with.mean())})  # fmt: skip
                r = rows[-1]
                print(
                    f"{loaded:<48} {how:<6} {r['mass']:.3f} kg (known {mass}, "
                    f"{100 * (r['mass'] / mass - 1):+.1f} %) com "
                    f"{', '.join(f'{c:.3f}' for c in r['com'])} m; held-out RMS "
                    f"{r['rms_without']:.3f} -> {r['rms_with']:.3f} N m",
                    file=out,
                )
    return rows


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=str(DATA), help="the logs' folder")
    p.add_argument("--smoke", action="store_true", help=f"{SMOKE_LOGS} logs, a check")
    p.add_argument("--payload", action="store_true", help="the known payloads instead")
    return page.add_option(p)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    name = "real_ur10e-payload" if args.payload else "real_ur10e"
    with page.recording(name, "real_ur10e", args.write_docs, argv, smoke=args.smoke):
        if args.payload:
            payloads(Path(args.data), out=sys.stdout)
        else:
            run(Path(args.data), smoke=args.smoke, out=sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
