"""The default `torchjfa identify` on a real KUKA LWR 4+ log, against hand-tuned least squares.

    python scripts/real_lwr4.py              # the last 30 % of the log held out (about a minute)
    python scripts/real_lwr4.py --origins    # the same at four split points (a few minutes)
    python scripts/real_lwr4.py --smoke      # a few seconds of it (a check, no result)
    python scripts/real_lwr4.py --write-docs # also into docs/benchmarks.md

The log is `../shared/data/kuka_lwr4_flobaroid` (its README: link-side torques of the FRI
recorded through ROS, positions filtered at 3 Hz and torques at 2 Hz before they were stored,
one slow sinusoid per joint; not shipped with the package). Without it the script says so and
stops (exit 0).

Rows and the one evaluation pipeline: `scripts/_real_arm.py`. The defaults are
``torchjfa identify robot.urdf measurements_1.csv`` and nothing else; the hand-tuned
reference is OLS with viscous, Coulomb and offset friction at the best of a few cut-offs
picked on the held-out part. The evaluation cut-off (5 Hz) lies above the filters the log was
stored with, so it leaves the stored signals as they are. Also printed: FloBaRoID's normalised
error (mean over the joints of RMS / (2 x the torque limit) x 100), whose published values on
this robot are 0.176-0.211 %.
"""

from __future__ import annotations

import sys

from _real_arm import SHARED, Arm, main

ARM = Arm(
    name="real_lwr4",
    title="KUKA LWR 4+",
    folder=SHARED / "kuka_lwr4_flobaroid",
    log="measurements_1.csv",
    robot="robot.urdf",
    defaults={},
    hand_friction=("viscous", "coulomb", "offset"),
    hand_cutoffs=(2.0, 3.0, 5.0, 10.0),
    eval_cutoff_hz=5.0,
    holdout=0.3,
    origins=(12.5, 15.0, 17.5, 20.0),
    window_s=4.0,
    limits=(176.0, 176.0, 100.0, 100.0, 100.0, 38.0, 38.0),
)

if __name__ == "__main__":
    sys.exit(main(ARM, doc=__doc__))
