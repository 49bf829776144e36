"""Command-line training of residual dynamics (`python -m torchjfa.learning.cli fit -c c.yaml`).

A `lightning.pytorch.cli.LightningCLI` over `ResidualDynamicsModule` and
`SimulatedLogDataModule`; every argument of the trainer, the model and the data module can be set
in the YAML file or on the command line (``--help`` lists them). ``data.identified`` follows
``model.identified`` (so the data module precomputes the regressor of the same model). An example
configuration is ``torchjfa/learning/configs/head_residual.yaml``.
"""

from __future__ import annotations

from lightning.pytorch.cli import LightningCLI

from ._data import SimulatedLogDataModule
from ._lightning import ResidualDynamicsModule

__all__ = ["ResidualCLI", "main"]


class ResidualCLI(LightningCLI):
    """`LightningCLI` with ``model.identified`` linked to ``data.identified``."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("model.identified", "data.identified")


def main(args=None, *, run: bool = True) -> ResidualCLI:
    """Run the CLI (``args``: a list of strings, default ``sys.argv[1:]``)."""
    return ResidualCLI(
        ResidualDynamicsModule,
        SimulatedLogDataModule,
        args=args,
        run=run,
        save_config_kwargs={"overwrite": True},
    )


if __name__ == "__main__":
    main()
