"""The default `torchjfa identify` on a real Stäubli TX40 log (coupled wrist), against hand-tuned
least squares.

    python scripts/real_tx40.py              # the last 30 % of the log held out (about a minute)
    python scripts/real_tx40.py --origins    # the same at four split points (a few minutes)
    python scripts/real_tx40.py --smoke      # a few seconds of it (a check, no result)
    python scripts/real_tx40.py --write-docs # also into docs/benchmarks.md

The log is `../shared/data/staubli_tx40_figaroh` (its README: the first 5.5 s of an excitation
run at 5 kHz, joint-side positions and torques converted from the motors through the gear
ratios, motor 6 turning joints 5 and 6; not shipped with the package). Without it the script
says so and stops (exit 0).

Rows and the one evaluation pipeline: `scripts/_real_arm.py`. The defaults are
``torchjfa identify robot.urdf LOG --transmission drive.json``, the transmission file written
by the script from the README's gear ratios (`TRANSMISSION`); the hand-tuned reference is the
coupled model: OLS with the same transmission and each motor's viscous, Coulomb and offset
friction and rotor inertia, at the best of a few cut-offs picked on the held-out part.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from _real_arm import SHARED, Arm, main

JOINTS = tuple(f"joint_{i}" for i in range(1, 7))
#: motor velocity = ratio @ joint velocity (the README: N = [32, 32, 45, -48, 45, 32], motor 6
#: also turning with joint 5)
TRANSMISSION = {
    "joints": list(JOINTS),
    "ratio": [
        [32, 0, 0, 0, 0, 0],
        [0, 32, 0, 0, 0, 0],
        [0, 0, 45, 0, 0, 0],
        [0, 0, 0, -48, 0, 0],
        [0, 0, 0, 0, 45, 0],
        [0, 0, 0, 0, 32, 32],
    ],
}


def write_transmission(folder: Path) -> Path:
    """`TRANSMISSION` as ``drive.json`` in ``folder``; its path."""
    path = Path(folder) / "drive.json"
    path.write_text(json.dumps(TRANSMISSION))
    return path


ARM = Arm(
    name="real_tx40",
    title="Stäubli TX40",
    folder=SHARED / "staubli_tx40_figaroh",
    log="tx40_excitation_first_5.5s.csv",
    robot="robot.urdf",
    defaults={"transmission": write_transmission},
    hand_friction=("viscous", "coulomb", "offset", "armature"),
    hand_cutoffs=(5.0, 10.0, 20.0, 40.0),
    eval_cutoff_hz=20.0,
    holdout=0.3,
    origins=(3.0, 3.5, 4.0, 4.5),
    window_s=0.9,
    smoke_s=3.0,
)

if __name__ == "__main__":
    sys.exit(main(ARM, doc=__doc__))
