"""``torchjfa residual``: residual dynamics trained with Lightning (``torchjfa residual fit
--config c.yaml``).

A `lightning.pytorch.cli.LightningCLI` over `torchjfa.learning.ResidualDynamicsModule` and
`torchjfa.learning.SimulatedLogDataModule`; every argument of the trainer, the model and the
data module can be set in the YAML file or on the command line (``torchjfa residual --help``
lists them). ``data.identified`` follows ``model.identified`` (so the data module precomputes
the regressor of the same model). An example configuration is
``torchjfa/learning/configs/head_residual.yaml``. This module imports Lightning; the
``torchjfa`` parser imports it only when the sub-command runs.
"""

from __future__ import annotations

from lightning.pytorch.cli import LightningCLI

from ..learning import ResidualDynamicsModule, SimulatedLogDataModule

__all__ = ["ResidualCLI", "main"]


class ResidualCLI(LightningCLI):
    """`LightningCLI` with ``model.identified`` linked to ``data.identified``."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("model.identified", "data.identified")


def main(args=None, *, run: bool = True) -> ResidualCLI:
    """Run the trainer's command line (``args``: a list of strings, default ``sys.argv[1:]``;
    ``run=False`` builds the model and data module without running a sub-command)."""
    return ResidualCLI(
        ResidualDynamicsModule,
        SimulatedLogDataModule,
        args=args,
        run=run,
        save_config_kwargs={"overwrite": True},
    )
