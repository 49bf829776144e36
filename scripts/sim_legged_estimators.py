"""Bayesian JFA against least squares on a simulated Go2 whose base motion is noisy.

    python scripts/sim_legged_estimators.py               # 60 s, noise x1 and x3
    python scripts/sim_legged_estimators.py --smoke       # 8 s, noise x3, two fits, a check
    python scripts/sim_legged_estimators.py --write-docs  # and into docs/benchmarks.md

A floating base's velocity and acceleration come from its pose (here differentiated from the
noisy pose, no IMU): errors in the variables of every row, which Bayesian JFA models and least
squares does not. The robot is example-robot-data's Go2 with every body perturbed by up to 20 %
(`torchjfa.sim.simulate_legged`, ``perturb=0.2``); one log identifies (with the sensor noise of
`torchjfa.sim.LEGGED_NOISE` times the scale), another motion (noise-free) judges. Each fit runs
`torchjfa.identification.identify_legged` with its defaults but the estimator:

* ``ols``: least squares (the default);
* ``bayes-jfa, learned``: Bayesian JFA learning the input noise from the data alone;
* ``bayes-jfa``: Bayesian JFA given the sensors' noise propagated into each column
  (``input_noise="auto"``, `propagated_legged_noise`): what ``--estimator bayes-jfa`` does.

Printed per fit: the held-out RMS (joint torques with forces, projected rows with flags) of
the identified model and of the unconstrained estimate, the total mass's error, the RMS of the
bodies' mass errors, and the fit's wall time.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import replace

import numpy as np
from sim_legged import CUTOFF_HZ, FEET, STANCE, command, judge

import torchjfa.robots
from torchjfa.identification import IdentificationWarning, Options, identify_legged
from torchjfa.sim import simulate_legged

FITS = (
    ("ols", {}),
    ("bayes-jfa, learned", {"estimator": "bayes-jfa", "input_noise": "learn"}),
    ("bayes-jfa", {"estimator": "bayes-jfa"}),
)


def main(argv=None) -> int:
    return command("sim_legged_estimators", __doc__, run, argv)


def run(seconds: float, smoke: bool) -> int:
    """Simulate, identify with each estimator and judge (the module); prints the table."""
    path = torchjfa.robots.example_robot_data_path("go2_description/urdf/go2.urdf")
    train = simulate_legged(path, FEET, STANCE, seconds=seconds, perturb=0.2, seed=1)
    test = simulate_legged(path, FEET, STANCE, seconds=5.0, perturb=0.2, seed=2)
    truth = train.theta.reshape(-1, 10)[:, 0]
    base = Options(cutoff=CUTOFF_HZ) if smoke else Options()
    print(f"{len(train.t)} training samples, {len(test.t)} held out; base motion from the pose")
    print(f"{'noise':6s} {'contacts':8s} {'estimator':19s} {'held-out RMS':>12s} "
          f"{'(estimate)':>10s} {'total mass':>10s} {'body masses':>11s} {'fit, s':>7s}")  # fmt: skip
    for scale in (3.0,) if smoke else (1.0, 3.0):
        noisy = replace(train.noisy(scale=scale, seed=0), imu={})
        for kind in ("forces", "flags"):
            log = noisy if kind == "forces" else replace(noisy, wrench={})
            for name, extra in FITS[::2] if smoke else FITS:  # no slow learned fit in a smoke run
                start = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", IdentificationWarning)
                    ident = identify_legged(path, log, base.replace(**extra))
                seconds_ = time.perf_counter() - start
                rms = judge(ident.model, test, kind)
                masses = np.array(list(ident.masses().values()))
                total = 100.0 * (masses.sum() / truth.sum() - 1.0)
                bodies = 100.0 * float(np.sqrt(np.mean((masses / truth - 1.0) ** 2)))
                print(f"x{scale:<5g} {kind:8s} {name:19s} {rms(ident.theta):12.4f} "
                      f"{rms(ident.theta_hat):10.4f} {total:+9.2f}% {bodies:10.1f}% "
                      f"{seconds_:7.1f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
