"""``python -m torchjfa.sim ROBOT``: deprecated, the same as ``torchjfa simulate ROBOT --full``.

    python -m torchjfa.sim head --n-samples 50000 --out head.npz
    torchjfa simulate head --n-samples 50000 --out head.npz --full     # what it runs

Its options (``--n-samples``, ``--no-unmodeled``, ``--noise-scale``, ``--seed``, ``--out``,
``--quiet``) are ``torchjfa simulate``'s; without ``--out`` the log goes to a temporary file
that is removed. Use ``torchjfa simulate``.
"""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path


def main(argv=None) -> int:
    """Run ``torchjfa simulate ... --full`` with these arguments; returns its exit status."""
    from torchjfa.cli import main as torchjfa

    argv = list(sys.argv[1:] if argv is None else argv)
    warnings.warn(
        "python -m torchjfa.sim is deprecated; use: torchjfa simulate ROBOT --out LOG.npz --full",
        FutureWarning,
        stacklevel=2,
    )
    if "--out" in argv or any(a.startswith("--out=") for a in argv):
        return torchjfa(["simulate", *argv, "--full"])
    with tempfile.TemporaryDirectory() as folder:
        return torchjfa(["simulate", *argv, "--full", "--out", str(Path(folder) / "log.npz")])


if __name__ == "__main__":
    sys.exit(main())
