"""Does the identified model make MuJoCo move like the real robot? Open-loop rollouts on real logs.

For the real Franka Panda log and the UR10e campaign (``../shared/data``; skipped where absent):
identify with the defaults on the first 80 % of the motion (the Panda; every UR10e log but one),
then roll the identified model's MJCF export and the description's MJCF out in MuJoCo from
measured states of the held-out part under its measured torques, open loop, over 50, 200 and
500 ms (`torchjfa.sim.replay`), and print the position error of each beside the description's.
The commands these calls stand for:

    torchjfa identify ROBOT TRAIN_LOG... [--drive-gains ...] --out result/
    torchjfa evaluate result/model.npz HELD_OUT_LOG [--drive-gains ...] --rollouts --out evaluation/

    python scripts/real_rollouts.py [--smoke]
    python scripts/real_rollouts.py --write-docs   # also into docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

import torchjfa
from torchjfa.identification import IdentificationWarning, evaluate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _benchmarks_page as page  # noqa: E402
import real_panda  # noqa: E402
import real_ur10e  # noqa: E402

#: the goal: the identified model's 200 ms rollout position error at most this times the
#: description's
GOAL = 1.0 / 3.0
UR10E_HELD_OUT = "ident_ur-20_02_19_15harm50sec.csv"


def _row(name: str, ev) -> dict:
    (replay,) = ev.rollouts.values()
    ident = replay.position["identified"].mean(axis=1)
    desc = replay.position["description"].mean(axis=1)
    return {"robot": name, "horizons": replay.horizons, "identified": ident, "description": desc}


def panda(smoke: bool = False) -> dict | None:
    """The Panda: identified on the first 80 % of the log's motion, rolled out on the rest."""
    if not (real_panda.DATA / "time.txt").is_file():
        return None
    log = real_panda.load_panda()
    if smoke:
        log = log.select(log.t < log.t[0] + 4 * real_panda.SMOKE_SECONDS)
    t_split = float(log.t[0] + 0.8 * (log.t[-1] - log.t[0]))
    head, tail = log.select(log.t < t_split), log.select(log.t >= t_split)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(real_panda.ROBOT, head)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.npz"
        ident.write(tmp, plots=False)
        ev = evaluate(path, tail, rollouts=True)
    return _row("panda (link-side torque sensors)", ev)


def ur10e(smoke: bool = False) -> dict | None:
    """The UR10e: identified on every unloaded log but one, rolled out on that one."""
    folder = real_ur10e.DATA
    if not (folder / "robot.urdf").is_file():
        return None
    held = folder / UR10E_HELD_OUT
    logs = [p for p in real_ur10e.identification_logs(folder) if p.name != held.name]
    if smoke:
        logs = logs[-real_ur10e.SMOKE_LOGS :]
    options = torchjfa.Options(drive_gains=list(real_ur10e.DRIVE_GAINS))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(str(folder / "robot.urdf"), [str(p) for p in logs], options)
    with tempfile.TemporaryDirectory() as tmp:
        ident.write(tmp, plots=False)
        ev = evaluate(Path(tmp) / "model.npz", str(held), options, rollouts=True)
    return _row("ur10e (motor currents)", ev)


def run(*, smoke: bool = False, out=sys.stdout) -> list[dict]:
    """Both robots' rows (those whose logs are present), printed."""
    rows = [r for r in (panda(smoke), ur10e(smoke)) if r is not None]
    print(f"{'robot':<34}{'horizon s':>10}{'identified rad':>16}{'description rad':>17}"
          f"{'ratio':>8}", file=out)  # fmt: skip
    for r in rows:
        for h, horizon in enumerate(r["horizons"]):
            ratio = r["identified"][h] / r["description"][h]
            print(f"{r['robot']:<34}{horizon:>10.3g}{r['identified'][h]:>16.4g}"
                  f"{r['description'][h]:>17.4g}{ratio:>8.3g}", file=out)  # fmt: skip
        at = r["horizons"].index(0.2)
        r["ratio_200ms"] = float(r["identified"][at] / r["description"][at])
        verdict = "met" if r["ratio_200ms"] <= GOAL else "NOT met"
        print(f"  {r['robot']}: 200 ms position error {r['ratio_200ms']:.3g}x the "
              f"description's (goal <= {GOAL:.3g}): {verdict}", file=out)  # fmt: skip
    if not rows:
        print("no real logs found", file=out)
    return rows


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--smoke", action="store_true", help="a few logs / seconds only")
    return page.add_option(p)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    with page.recording("real_rollouts", "real_rollouts", args.write_docs, argv, smoke=args.smoke):
        run(smoke=args.smoke, out=sys.stdout)
    return 0


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    raise SystemExit(main())
