"""Refine the identified joint terms on real logs with mujoco.sysid, kept where held-out rollouts
improve.

    python scripts/real_refine.py            # both robots, the full fit (minutes)
    python scripts/real_refine.py --smoke    # a few logs / seconds, a short fit: a check
    python scripts/real_refine.py --write-docs   # also into docs/benchmarks.md

For the real UR10e campaign and the Franka Panda log in ``../shared/data`` (each skipped where
absent; neither is shipped), the robot is identified with the defaults as
``scripts/real_rollouts.py`` does, then `torchjfa.sim.refine` fits each joint's friction loss,
damping and armature and one torque delay on open-loop MuJoCo rollouts (``mujoco.sysid``,
``pip install "torchjfa[sysid]"``) and keeps what its acceptance part confirms. Three parts of
the data, none seen by the next:

* UR10e (motor currents): identified on every unloaded log but ``UR10E_HELD_OUT``; the
  refinement fits on ``FIT_LOGS`` and accepts on ``ACCEPT_LOG`` (identification logs the fit
  did not see); the table is on ``UR10E_HELD_OUT``, which neither saw.
* Panda (link-side torque sensors): identified on the first 80 % of the log; the refinement fits
  on the first 70 % and accepts on 70-80 %; the table is on the last 20 %.

Printed per robot: the 50/200/500 ms open-loop rollout position error (mean over joints, rad)
of the description, the identified model and the refined model on the last part
(`torchjfa.sim.replay`, as ``torchjfa evaluate --rollouts``), then the refined values and the
verdicts. The logs are prepared as ``torchjfa evaluate`` prepares them (the identification's
cut-off, the measured torque unfiltered).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import torch

import torchjfa
from torchjfa.identification import IdentificationWarning, evaluate
from torchjfa.sim import refine

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _benchmarks_page as page  # noqa: E402
import real_panda  # noqa: E402
import real_rollouts  # noqa: E402
import real_ur10e  # noqa: E402

UR10E_HELD_OUT = real_rollouts.UR10E_HELD_OUT
FIT_LOGS = ("ident_ur-20_02_12-50sec_12harm.csv", "ident_ur-20_02_10-30sec_12harm.csv")
ACCEPT_LOG = "ident_ur-20_02_19_14harm50sec.csv"
PARAMETERS = ("frictionloss", "damping", "armature", "delay")
#: the full fit, and the smoke check's
FULL = {"max_windows": 64, "max_iters": 30}
SMOKE = {"max_windows": 12, "max_iters": 3, "starts": 10}


def _prepared(identified: Path, logs, options=None) -> list:
    """The logs as `evaluate` prepares them (the held-out target: the measured torque)."""
    ev = evaluate(identified, logs, options)
    return [log for log, _ in ev.logs.values()]


def _refined(name: str, identified: Path, fit, accept, test, options, smoke: bool) -> dict:
    """Refine on ``fit``, accept on ``accept``, roll the three models out on ``test``."""
    ev = evaluate(identified, test, options, rollouts=True)
    (replay,) = ev.rollouts.values()
    (test_log,) = [log for log, _ in ev.logs.values()]
    started = time.perf_counter()
    refinement = refine(
        ev.model,
        ev.theta,
        _prepared(identified, fit, options),
        _prepared(identified, accept, options),
        parameters=PARAMETERS,
        **(SMOKE if smoke else FULL),
    )
    seconds = time.perf_counter() - started
    refined = refinement.replay(test_log, starts=replay.starts)
    return {
        "robot": name,
        "horizons": replay.horizons,
        "description": replay.position["description"].mean(axis=1),
        "identified": replay.position["identified"].mean(axis=1),
        "refined": refined.position["refined"].mean(axis=1),
        "refinement": refinement,
        "seconds": seconds,
    }


def _identified(tmp: str, robot, logs, options=None) -> Path:
    """`torchjfa.identify` with the defaults, written to ``tmp``: its ``model.npz``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(robot, logs, options)
    ident.write(tmp, plots=False)
    return Path(tmp) / "model.npz"


def ur10e(smoke: bool = False) -> dict | None:
    """The UR10e: identified on every unloaded log but UR10E_HELD_OUT (the last SMOKE_LOGS of
    them with ``smoke``), refined on FIT_LOGS (one with ``smoke``), accepted on ACCEPT_LOG."""
    folder = real_ur10e.DATA
    if not (folder / "robot.urdf").is_file():
        return None
    logs = [p for p in real_ur10e.identification_logs(folder) if p.name != UR10E_HELD_OUT]
    if smoke:
        logs = logs[-real_ur10e.SMOKE_LOGS :]
    options = torchjfa.Options(drive_gains=list(real_ur10e.DRIVE_GAINS))
    fit = [str(folder / f) for f in FIT_LOGS[: 1 if smoke else None]]
    with tempfile.TemporaryDirectory() as tmp:
        path = _identified(tmp, str(folder / "robot.urdf"), [str(p) for p in logs], options)
        return _refined("ur10e (motor currents)", path, fit, str(folder / ACCEPT_LOG),
                        str(folder / UR10E_HELD_OUT), options, smoke)  # fmt: skip


def panda(smoke: bool = False) -> dict | None:
    """The Panda: identified on the first 80 % of the log (of its first 40 s with ``smoke``),
    refined on the first 70 %, accepted on 70-80 %, judged on the last 20 %."""
    if not (real_panda.DATA / "time.txt").is_file():
        return None
    log = real_panda.load_panda()
    if smoke:
        log = log.select(log.t < log.t[0] + 4 * real_panda.SMOKE_SECONDS)
    t = log.t
    at = [float(t[0] + f * (t[-1] - t[0])) for f in (0.7, 0.8)]
    head, tail = log.select(t < at[1]), log.select(t >= at[1])
    fit, accept = log.select(t < at[0]), log.select((t >= at[0]) & (t < at[1]))
    with tempfile.TemporaryDirectory() as tmp:
        path = _identified(tmp, real_panda.ROBOT, head)
        return _refined("panda (link-side torque sensors)", path, fit, accept, tail, None, smoke)


def _print(r: dict, out) -> None:
    print(f"\n{r['robot']}: refined in {r['seconds']:.0f} s", file=out)
    print(f"{'horizon s':>10}{'description':>14}{'identified':>14}{'refined':>14}"
          f"{'refined/identified':>20}", file=out)  # fmt: skip
    for h, horizon in enumerate(r["horizons"]):
        print(f"{horizon:>10.3g}{r['description'][h]:>14.4g}{r['identified'][h]:>14.4g}"
              f"{r['refined'][h]:>14.4g}{r['refined'][h] / r['identified'][h]:>20.3g}",
              file=out)  # fmt: skip
    refinement = r["refinement"]
    print("the refined values (identified -> fitted; kept or not) and the verdicts:", file=out)
    for line in refinement.lines():
        print("  " + line, file=out)
    for joint, why in refinement.reasons.items():
        if joint not in ("whole", "delay"):
            print(f"    {joint}: {why}", file=out)
    fit = refinement.fit
    print(f"  fit: {fit['windows']} windows of {fit['window_s']:.3g} s, {fit['parameters']} "
          f"values, {fit['iterations']} iterations, cost {fit['cost_start']:.4g} -> "
          f"{fit['cost_end']:.4g}, {fit['seconds']:.0f} s; judged in "
          f"{fit['judge_seconds']:.0f} s", file=out)  # fmt: skip


def run(*, smoke: bool = False, out=sys.stdout) -> list[dict]:
    """Both robots' rows (those whose logs are present), printed."""
    torch.set_num_threads(1)
    rows = []
    for robot in (ur10e, panda):
        r = robot(smoke)
        if r is not None:
            _print(r, out)
            rows.append(r)
    if not rows:
        print("no real logs found in ../shared/data: nothing to do", file=out)
    return rows


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--smoke", action="store_true", help="a few logs / seconds, a short fit")
    return page.add_option(p)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    with page.recording("real_refine", "real_refine", args.write_docs, argv, smoke=args.smoke):
        try:
            run(smoke=args.smoke, out=sys.stdout)
        except ImportError as exc:  # without the extra
            print(f"no refinement: {exc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
