"""The ``torchjfa`` command: every command line of the library, each a thin module over its
public functions.

    torchjfa excite panda_arm --out traj/                        # an excitation to run
    torchjfa simulate head --out log.csv                          # or a simulated log
    torchjfa identify head log.csv --estimator bayes-jfa --out result/
    torchjfa evaluate result/model.npz run3.csv --out evaluation/
    torchjfa evaluate result/model.npz --robot head
    torchjfa payload result/model.npz loaded.csv --link tool0 --out payload/
    torchjfa refine result/model.npz run1.csv --held-out run2.csv --out refined/
    torchjfa residual fit --config torchjfa/learning/configs/head_residual.yaml

One module per sub-command: ``_identify`` (`torchjfa.identify`, its flags generated from
`torchjfa.Options`), ``_simulate`` (`torchjfa.sim.simulate`), ``_excite``
(`torchjfa.excitation.design_excitation`), ``_evaluate`` (`torchjfa.identification.evaluate`,
`torchjfa.sim.evaluate_simulated`), ``_payload`` (`torchjfa.identification.identify_payload`,
`identify_drive_gains`), ``_refine`` (`torchjfa.sim.refine`) and ``_residual`` (Lightning's
command line over `torchjfa.learning`). Options that mirror a library argument take its
default from the library (`Options`' fields, the functions' signatures). Bad input ends with
one line on stderr and exit status 2, not a traceback; ``--debug`` shows the traceback. No
module of the library imports this package.
"""

from typing import TYPE_CHECKING

from ._main import COMMANDS as COMMANDS
from ._main import build_parser as build_parser
from ._main import entry as entry
from ._main import main as main

if TYPE_CHECKING:
    from ._common import UsageError as UsageError
    from ._common import load_model as load_model
    from ._identify import identify_options as identify_options
    from ._main import ESTIMATORS as ESTIMATORS

__all__ = [
    "COMMANDS", "ESTIMATORS", "UsageError", "build_parser", "entry", "identify_options",
    "load_model", "main",
]  # fmt: skip

_entry = entry  # the console script's earlier target, kept for installs made before it moved

#: names imported when first asked for (``torchjfa --help`` imports neither torch nor the flow)
_LAZY = {"UsageError": "_common", "load_model": "_common", "identify_options": "_identify",
         "ESTIMATORS": "_main"}  # fmt: skip


def __getattr__(name: str):
    if name in _LAZY:
        from importlib import import_module

        return getattr(import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
