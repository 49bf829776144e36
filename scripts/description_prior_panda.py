"""The description as a prior on the real Panda log: link masses and held-out RMS with and without.

Reads ``../shared/data/panda_gaz2019`` (skips with a message when absent), prepares it at one
cut-off (``--cutoff``, default 8 Hz) with viscous + Coulomb + offset friction, holds out the last
20% and identifies with OLS and the log-Cholesky projection, once without a prior and once with
``identify(..., description_prior=w)`` for ``w = "auto"`` and fixed weights. Prints, per run, the
held-out RMS per joint and its mean (against the torque filtered at the same cut-off), the link
masses against the description's, and the base-parameter summary of the training data.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

import torchjfa
from torchjfa.data import JointLog, prepare
from torchjfa.dynamics import RigidBodyModel
from torchjfa.estimators import OLS
from torchjfa.physical import base_parameters, check
from torchjfa.pipeline import identify
from torchjfa.report import predicted_torques

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "panda_gaz2019"


def load(folder: Path) -> JointLog:
    t = np.loadtxt(folder / "time.txt")
    n = t.shape[0]
    arr = {
        k: np.loadtxt(folder / f"{f}.txt").reshape(n, 7)
        for k, f in (("q", "positions"), ("qd", "velocity"), ("tau", "torques"))
    }
    names = tuple(f"panda_joint{k}" for k in range(1, 8))
    return JointLog(
        t=torch.from_numpy(t), joint_names=names, **{k: torch.from_numpy(v) for k, v in arr.items()}
    )


def run(cutoff: float = 8.0, weights=("auto", 100.0, 1e4), folder: Path = DATA):
    if not folder.is_dir():
        print(f"skipped: no data in {folder}")
        return None
    model = RigidBodyModel.from_urdf(
        torchjfa.robots.path("panda_arm"), friction=("viscous", "coulomb", "offset")
    )
    data = prepare(load(folder).reorder(model.joint_names), cutoff_hz=cutoff, period_s=None)
    gap = int(4.0 / cutoff * data.info["rate_hz"])
    train, valid = data.split(0.2, gap=gap)
    nominal = model.nominal_theta
    base = base_parameters(
        identify(model, train, estimator=OLS(fit_intercept=False), project=False).moments, model
    )
    print(f"training data: {train.n_samples} samples; {base.summary()}")
    masses = {"description": nominal.reshape(7, -1)[:, 0]}
    rows = {}
    for w in (None, *weights):
        start = time.perf_counter()
        res = identify(
            model,
            train,
            estimator=OLS(fit_intercept=False),
            parametrization="log-cholesky",
            description_prior=w,
        )
        pred = predicted_torques(model, res.theta, valid.q, valid.qd, valid.qdd, valid.tau)
        rms = (pred - valid.tau).pow(2).mean(0).sqrt()
        label = "no prior" if w is None else f"prior {w} (weight {res.prior_weight:g})"
        rows[label] = rms
        masses[label] = res.theta.reshape(7, -1)[:, 0]
        print(
            f"{label}: held-out mean RMS {float(rms.mean()):.4f} N m (quadratic mean "
            f"{float(rms.pow(2).mean().sqrt()):.4f}), per joint "
            + " ".join(f"{float(v):.3f}" for v in rms)
            + f"; train RMS {res.rmse():.4f}; fully consistent {check(res.theta, model).ok}; "
            f"{time.perf_counter() - start:.1f} s"
        )
        if res.prior_choice:
            print(
                "  choice (cross-validated RMS over the training blocks): "
                + ", ".join(f"{k:g}: {v:.4f}" for k, v in res.prior_choice.items())
            )
    print("link masses, kg:")
    for k, m in masses.items():
        print(f"  {k:<28} " + " ".join(f"{float(x):7.3f}" for x in m))
    return rows, masses


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cutoff", type=float, default=8.0)
    ap.add_argument("--data", default=os.fspath(DATA))
    a = ap.parse_args()
    run(a.cutoff, folder=Path(a.data))
