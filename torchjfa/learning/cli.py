"""``python -m torchjfa.learning.cli``: deprecated, the same as ``torchjfa residual``.

    torchjfa residual fit --config torchjfa/learning/configs/head_residual.yaml

`ResidualCLI` and `main` live in the command-line package (``torchjfa.cli._residual``); this
module re-exports them and warns when imported.
"""

from __future__ import annotations

import warnings

from torchjfa.cli._residual import ResidualCLI as ResidualCLI
from torchjfa.cli._residual import main as main

warnings.warn(
    "torchjfa.learning.cli is deprecated; use the torchjfa residual command "
    "(torchjfa.cli._residual)",
    FutureWarning,
    stacklevel=2,
)

if __name__ == "__main__":
    main()
