"""Drive gains of the real UR10e from a payload of known mass, checked on a loaded run not used
to find them.

    python scripts/real_ur10e_gains.py           # about two minutes
    python scripts/real_ur10e_gains.py --smoke   # fewer logs and blocks: a check, no result
    python scripts/real_ur10e_gains.py --swap    # the gains from the other pair
    python scripts/real_ur10e_gains.py --write-docs   # also into docs/benchmarks.md

The logs are `../shared/data/ur10e_mamedov2020` (motor currents; not shipped with the
package). Without them the script says so and stops (exit 0).

1. The robot is identified with the defaults from every unloaded identification log, read with
   the dataset README's gains (``DRIVE_GAINS``): the structure and the start of the fit.
2. `torchjfa.identification.identify_drive_gains` on the pair ``14harm50secLoad`` (2.805 kg on
   ``ee_link``) / ``14harm50sec``: the gains with jackknife spreads, against the README's (which
   its authors derived from the same pair with the first joint's gain held at a bound).
3. The check, on the other documented pair (``load_2600``, 2.602 kg, with its unloaded twin),
   which step 2 does not see: for each set of gains (the README's, the identified), the robot
   is identified again from the unloaded logs read with them, and the 2.602 kg payload is
   identified from its pair and from the loaded run against the robot alone
   (`identify_payload`). Printed: the payload's mass against 2.602 kg, and the held-out current
   RMS of the loaded run (the last part of it, with the payload model; in amperes, so that the
   two sets of gains are judged in the same unit).

``--swap`` exchanges the pairs: the gains from the 2.602 kg pair, checked on the 2.805 kg one.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import torch

import torchjfa
from torchjfa.identification import IdentificationWarning, identify_drive_gains, identify_payload

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _benchmarks_page as page  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "ur10e_mamedov2020"
#: the gains in the dataset's README, N m/A, joints 1-6
DRIVE_GAINS = (10.0, 10.6956, 8.4566, 9.0029, 9.48, 10.1232)
LINK = "ee_link"
#: (loaded, unloaded, kg): the pair the gains come from, and the pair that checks them
FIT_PAIR = (
    "ident_payload_ur-20_02_19_14harm50secLoad.csv",
    "ident_ur-20_02_19_14harm50sec.csv",
    2.805,
)
CHECK_PAIR = ("ident_payload_ur-20_01_13-load_2600.csv", "ident_ur-19_12_23_free.csv", 2.602)
SMOKE_LOGS = 3


def _robot(folder: Path, gains, tmp: Path, smoke: bool) -> Path:
    """``model.npz`` of the robot identified with the defaults, logs read with ``gains``."""
    paths = sorted(folder.glob("ident_ur-*.csv"))[: SMOKE_LOGS if smoke else None]
    options = torchjfa.Options(drive_gains=list(gains))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        ident = torchjfa.identify(folder / "robot.urdf", paths, options)
    return ident.write(tmp, plots=False)["model"]


def run(
    folder: Path = DATA, *, smoke: bool = False, swap: bool = False, out=sys.stdout
) -> dict | None:
    """Steps 1-3 of the module (``swap``: the gains from `CHECK_PAIR`, checked on
    `FIT_PAIR`); the numbers, or None without the logs."""
    import tempfile

    fit_pair, check_pair = (CHECK_PAIR, FIT_PAIR) if swap else (FIT_PAIR, CHECK_PAIR)
    if not (folder / CHECK_PAIR[0]).is_file():
        print(f"no UR10e logs in {folder}; nothing to do", file=out)
        return None
    result: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        model = _robot(folder, DRIVE_GAINS, tmp / "readme", smoke)
        loaded, free, mass = fit_pair
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentificationWarning)
            found = identify_drive_gains(
                model, folder / loaded, folder / free, link=LINK, mass=mass,
                options=torchjfa.Options(drive_gains=list(DRIVE_GAINS)), blocks=4 if smoke else 10,
            )  # fmt: skip
        print(f"drive gains from {loaded} / {free} ({mass} kg on {LINK}), N m/A:", file=out)
        print(found.table(), file=out)
        result["gains"] = found.summary()
        sets = {"README": DRIVE_GAINS, "identified": tuple(found.gains.tolist())}
        loaded, free, mass = check_pair
        print(f"\ncheck on {loaded} / {free} ({mass} kg), not used above:", file=out)
        for name, gains in sets.items():
            # the README's robot is the one identified above
            robot = model if gains == DRIVE_GAINS else _robot(folder, gains, tmp / name, smoke)
            options = torchjfa.Options(drive_gains=list(gains))
            result[name] = {}
            for way, unloaded in (("pair", folder / free), ("robot", None)):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", IdentificationWarning)
                    p = identify_payload(
                        robot, folder / loaded, link=LINK, unloaded=unloaded, options=options
                    )
                current = p.rms_with / torch.tensor(gains, dtype=torch.float64)  # A
                result[name][way] = {"mass": p.mass, "current_rms": current.tolist()}
                print(
                    f"  {name:<10} gains, {way:<5}: payload {p.mass:.3f} kg "
                    f"({100 * (p.mass / mass - 1):+.1f} %); held-out current RMS "
                    f"{float(current.mean()):.4f} A "
                    f"(per joint {', '.join(f'{c:.3f}' for c in current.tolist())})",
                    file=out,
                )
    return result


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=str(DATA), help="the logs' folder")
    p.add_argument("--smoke", action="store_true", help=f"{SMOKE_LOGS} logs, a check")
    p.add_argument("--swap", action="store_true", help="the gains from the other pair")
    return page.add_option(p)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    name = "real_ur10e_gains-swap" if args.swap else "real_ur10e_gains"
    with page.recording(name, "real_ur10e_gains", args.write_docs, argv, smoke=args.smoke):
        run(Path(args.data), smoke=args.smoke, swap=args.swap, out=sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
