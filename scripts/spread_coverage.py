"""Do the spreads of the unconstrained estimate cover the truth? Coverage over simulated logs.

``--logs`` simulated logs of the head (`torchjfa.sim.generate_log`, seed = log number: a new
excitation and new sensor noise each; the default `SensorNoise`; ``unmodeled=False`` so that
the model, rigid body + viscous friction, is exact and the truth is the file's inertials and
damping). Each is identified by `torchjfa.identify` with the library's defaults (the cut-off
chosen on the log, residual joint weights, ``--input-noise auto``, the bias correction:
`torchjfa.identification.simex_bias` from ``--draws`` refits), unprojected, with OLS and with
Bayesian JFA (at the cut-off OLS's run chose: equal preparation). For each, in the log's
base-parameter coordinates (`IdentificationReport.base`: the identifiable combinations; the
truth mapped the same way), three spreads:

- own: OLS's least-squares std (`BaseParameters.std`), Bayesian JFA's posterior std
  (``coef_std_``, mapped as independent: ``var_B + beta^2 var_dep``);
- jackknife: delete-one-block over ``--blocks`` blocks (`BaseParameters.jackknife_std`), what
  the report shows;
- bootstrap: the spread of the bias correction's refits on the raw log with re-drawn sensor
  noise (its spectral estimate) through the whole preparation (`signal_bootstrap`'s; Bayesian
  JFA's refits are given twice the input noise, as their data carry).

The rows measure the error of the flow's estimate, corrected for the errors-in-variables bias
(the refits carry the log's noise plus one more draw of it, so their mean moves from the
estimate by about the bias the noise gives it, which no spread covers; the flow subtracts that
once more, extrapolating linearly to no noise: SIMEX with noise multiples 1 and 2); the
", uncorrected" rows the error of the estimate without it.

Prints, per estimator and spread, the coverage of +-1 and +-1.96 spreads (nominal 68 % and
95 %): pooled over every base parameter of every log, and the median over logs of each log's
coverage. The target is 60-76 % and 90-98 %.

    python scripts/spread_coverage.py              # 50 logs of 4000 samples (3-6 minutes)
    python scripts/spread_coverage.py --smoke      # 2 logs of 1500 samples, 3 draws (seconds)
    python scripts/spread_coverage.py --write-docs # also into docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import time
import warnings

import _benchmarks_page as page
import torch

import torchjfa
from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import IdentificationWarning, Options
from torchjfa.sim import generate_log, model_path, true_parameters

ESTIMATORS = {"OLS": "ols", "Bayesian JFA": "bayes-jfa"}
SPREADS = ("own", "jackknife", "bootstrap")
#: the same spreads about the estimate without the bias correction (`one_log`)
AGAINST = (*SPREADS, *(f"{s}, uncorrected" for s in SPREADS))
LEVELS = (("68%", 1.0), ("95%", 1.96))


def truth(robot: str) -> tuple[RigidBodyModel, torch.Tensor]:
    """The identification model (rigid body + viscous friction) and its true parameters."""
    model = RigidBodyModel.from_mjcf(model_path(robot), friction=("viscous",))
    return model, true_parameters(robot, model)


def own_std(ident, base) -> torch.Tensor:
    """The estimator's own spread in base coordinates: least squares, or the posterior."""
    post = getattr(ident.result.estimator, "coef_std_", None)
    if post is None:
        return base.std
    var = post.to(torch.float64).pow(2)
    out = var[list(base.independent)]
    if base.dependent:
        out = out + base.beta.pow(2) @ var[list(base.dependent)]
    return out.sqrt()


def one_log(robot, model, theta, seed, *, n_samples, blocks, draws) -> dict:
    """``{estimator: {spread: (rank,) z-scores (estimate - truth) / spread}}`` for one log, for
    the flow's estimate (bias-corrected) and for the uncorrected one (``"<spread>,
    uncorrected"``), and the noise mode."""
    log = generate_log(robot, n_samples=n_samples, unmodeled=False, seed=seed)
    out, cutoff = {}, "auto"
    for name, est in ESTIMATORS.items():
        opts = Options(
            estimator=est, project=False, jackknife=blocks, bias_correction=draws, cutoff=cutoff
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentificationWarning)
            ident = torchjfa.identify(model, log, opts)
        cutoff = ident.data.cutoff_hz  # the next estimator at the same preparation
        res, base = ident.result, ident.report.base
        err = base.values(res.theta_hat) - base.values(theta)
        # the bias correction subtracted theta_hat_bias (from the jackknife's refits too)
        err_raw = err + base.values(res.theta_hat_bias)
        spreads = {
            "own": own_std(ident, base),
            "jackknife": base.jackknife_std(res.theta_hat_jackknife),
            "bootstrap": base.values(res.theta_hat_redrawn).std(dim=0, correction=1),
        }
        out[name] = {k: err / v for k, v in spreads.items()}
        out[name].update({f"{k}, uncorrected": err_raw / v for k, v in spreads.items()})
        out[name]["noise"] = ident.noise.mode
    return out


def coverage(z: list[torch.Tensor], level: float) -> tuple[float, float]:
    """(pooled, median over logs) fraction of ``|z| < level``."""
    inside = [(v.abs() < level).to(torch.float64) for v in z]
    pooled = float(torch.cat(inside).mean())
    return pooled, float(torch.stack([v.mean() for v in inside]).median())


def run(robot="head", *, logs=50, n_samples=4000, blocks=20, draws=20, progress=True) -> dict:
    model, theta = truth(robot)
    z = {e: {s: [] for s in AGAINST} for e in ESTIMATORS}
    modes = {e: set() for e in ESTIMATORS}
    started = time.perf_counter()
    for seed in range(logs):
        one = one_log(robot, model, theta, seed, n_samples=n_samples, blocks=blocks, draws=draws)
        for e in ESTIMATORS:
            modes[e].add(one[e]["noise"])
            for s in AGAINST:
                z[e][s].append(one[e][s])
        if progress:
            print(f"  log {seed + 1}/{logs} ({time.perf_counter() - started:.0f} s)", flush=True)
    table = {
        e: {s: {lvl: coverage(z[e][s], c) for lvl, c in LEVELS} for s in AGAINST}
        for e in ESTIMATORS
    }
    median_abs_z = {e: {s: float(torch.cat(z[e][s]).abs().nanmedian()) for s in AGAINST} for e in z}
    return {
        "robot": robot,
        "logs": logs,
        "n_samples": n_samples,
        "blocks": blocks,
        "draws": draws,
        "rank": int(z["OLS"]["own"][0].numel()),
        "input_noise": {e: sorted(m) for e, m in modes.items()},
        "coverage": table,
        "median_abs_z": median_abs_z,
        "seconds": time.perf_counter() - started,
    }


def parser() -> argparse.ArgumentParser:
    """The command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="head", choices=("head", "arm"), help="the robot")
    ap.add_argument("--logs", type=int, default=50, help="simulated logs")
    ap.add_argument("--samples", type=int, default=4000, help="samples per log")
    ap.add_argument("--blocks", type=int, default=20, help="jackknife blocks")
    ap.add_argument(
        "--draws", type=int, default=20, help="refits of the bias correction (its bootstrap)"
    )
    ap.add_argument("--smoke", action="store_true", help="2 logs of 1500 samples, 3 draws")
    return page.add_option(ap)


def table_markdown(printed: str) -> str:
    """What ``--write-docs`` writes: the printed table, the progress lines left out."""
    lines = [line for line in printed.splitlines() if not line.startswith("  log ")]
    return page.fenced("\n".join(lines))


def main(argv=None) -> dict:
    args = parser().parse_args(argv)
    name = "spread_coverage" if args.robot == "head" else f"spread_coverage-{args.robot}"
    with page.recording(
        name, "spread_coverage", args.write_docs, argv, smoke=args.smoke, markdown=table_markdown
    ):
        return _main(args)


def _main(args) -> dict:
    """Run and print what ``args`` ask for."""
    if args.smoke:
        args.logs, args.samples, args.draws, args.blocks = 2, 1500, 3, 4
    out = run(
        args.robot,
        logs=args.logs,
        n_samples=args.samples,
        blocks=args.blocks,
        draws=args.draws,
        progress=not args.smoke,
    )
    print(
        f"{out['robot']}: {out['logs']} simulated logs of {out['n_samples']} samples, "
        f"{out['rank']} base parameters each (first log); jackknife over {out['blocks']} "
        f"blocks, bootstrap over {out['draws']} re-drawn sensor noises; input noise: "
        + ", ".join(f"{e} {'/'.join(m)}" for e, m in out["input_noise"].items())
    )
    print("coverage of +-1 and +-1.96 spreads (pooled over logs | median per log); target")
    print("60-76 % and 90-98 %; median |error| / spread (0.67 when calibrated)")
    print(
        f"{'estimator':>13} {'spread':>20} {'68% pooled':>11} {'median':>7} "
        f"{'95% pooled':>11} {'median':>7} {'med |z|':>8}"
    )
    for e, rows in out["coverage"].items():
        for s, cov in rows.items():
            p68, m68 = cov["68%"]
            p95, m95 = cov["95%"]
            print(
                f"{e:>13} {s:>20} {p68:>11.1%} {m68:>7.1%} {p95:>11.1%} {m95:>7.1%} "
                f"{out['median_abs_z'][e][s]:>8.2f}"
            )
    print(f"({out['seconds']:.0f} s)")
    return out


if __name__ == "__main__":
    main()
