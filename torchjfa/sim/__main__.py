"""``python -m torchjfa.sim ROBOT``: deprecated, the same as ``torchjfa simulate ROBOT --full``.

    python -m torchjfa.sim head --n-samples 50000 --out head.npz
    torchjfa simulate head --n-samples 50000 --out head.npz --full     # what it runs

Its options (``--n-samples``, ``--no-unmodeled``, ``--noise-scale``, ``--seed``, ``--out``,
``--quiet``) are ``torchjfa simulate``'s; without ``--out`` the log goes to a temporary file
that is removed. Use ``torchjfa simulate``; `run`, its function, is deprecated too.
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from pathlib import Path

from ._generate import DEFAULT_N_SAMPLES, generate_log
from ._log import SensorNoise

_DEPRECATED = (
    "python -m torchjfa.sim is deprecated; use: torchjfa simulate ROBOT --out LOG.npz --full "
    "(torchjfa.sim.simulate from Python)"
)


def run(
    robot: str = "head",
    *,
    n_samples: int = DEFAULT_N_SAMPLES,
    unmodeled: bool = True,
    noise_scale: float = 1.0,
    seed: int = 0,
    out: str | None = None,
    progress: bool = True,
) -> dict[str, float]:
    """Deprecated: generate (and optionally save) a log; return its size, wall time and samples
    per second. Use `torchjfa.sim.simulate` (or `generate_log`)."""
    warnings.warn(_DEPRECATED, FutureWarning, stacklevel=2)
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


def main(argv=None) -> int:
    """Run ``torchjfa simulate ... --full`` with these arguments; returns its exit status."""
    from torchjfa.cli import main as torchjfa

    argv = list(sys.argv[1:] if argv is None else argv)
    warnings.warn(_DEPRECATED, FutureWarning, stacklevel=2)
    if "--out" in argv or any(a.startswith("--out=") for a in argv):
        return torchjfa(["simulate", *argv, "--full"])
    with tempfile.TemporaryDirectory() as folder:
        return torchjfa(["simulate", *argv, "--full", "--out", str(Path(folder) / "log.npz")])


if __name__ == "__main__":
    sys.exit(main())
