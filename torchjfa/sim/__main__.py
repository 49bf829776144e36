"""Generate a simulated identification log from the command line and report its speed.

    python -m torchjfa.sim head --n-samples 500000 --out head.npz

prints the simulation's samples per second (the whole `generate_log`, differentiation included)
and, when ``--out`` is given, saves the `SimulatedLog`.
"""

from __future__ import annotations

import argparse
import time

from ._generate import generate_log
from ._log import SensorNoise


def run(
    robot: str = "head",
    *,
    n_samples: int = 500_000,
    unmodeled: bool = True,
    noise_scale: float = 1.0,
    seed: int = 0,
    out: str | None = None,
    progress: bool = True,
) -> dict[str, float]:
    """Generate (and optionally save) a log; return its size, wall time and samples per second."""
    noise = SensorNoise().scaled(noise_scale)
    start = time.perf_counter()
    log = generate_log(
        robot, n_samples=n_samples, unmodeled=unmodeled, noise=noise, seed=seed, progress=progress
    )
    seconds = time.perf_counter() - start
    if out is not None:
        log.save(out)
    return {
        "n_samples": float(log.n_samples),
        "seconds": seconds,
        "samples_per_second": log.n_samples / seconds,
        "simulated_seconds": log.n_samples / log.control_rate,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("robot", choices=["head", "arm"])
    parser.add_argument("--n-samples", type=int, default=500_000)
    parser.add_argument("--no-unmodeled", action="store_true", help="armature etc. off")
    parser.add_argument("--noise-scale", type=float, default=1.0, help="x the default noise")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="save the log to this .npz path")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    res = run(
        args.robot,
        n_samples=args.n_samples,
        unmodeled=not args.no_unmodeled,
        noise_scale=args.noise_scale,
        seed=args.seed,
        out=args.out,
        progress=not args.quiet,
    )
    print(
        f"{args.robot}: {int(res['n_samples'])} samples ({res['simulated_seconds']:.0f} s "
        f"simulated) in {res['seconds']:.1f} s wall: {res['samples_per_second']:.0f} samples/s, "
        f"{res['simulated_seconds'] / res['seconds']:.1f}x real time"
    )


if __name__ == "__main__":
    main()
