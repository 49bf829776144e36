"""torchjfa: probabilistic system identification of robots in PyTorch.

The flow: a robot description (URDF/MJCF) gives a `RigidBodyModel`, whose batched regressor
turns joint logs into `Moments`; an estimator (Bayesian joint factor analysis regression or a
baseline, `torchjfa.estimators`) fits parameters from the moments; `torchjfa.physical.project`
makes them physically consistent; `InverseDynamics` returns the identified model as an
``nn.Module``. `torchjfa.sim` simulates robots in MuJoCo and evaluates identified models.
"""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from . import estimators as estimators
    from . import physical as physical
    from . import robots as robots
    from .dynamics import InverseDynamics as InverseDynamics
    from .dynamics import ParameterLayout as ParameterLayout
    from .dynamics import RigidBodyModel as RigidBodyModel
    from .estimators import BayesianJFA as BayesianJFA
    from .identification import Identification as Identification
    from .identification import Options as Options
    from .identification import identify as identify
    from .stats import Moments as Moments
    from .stats import kfold_moments as kfold_moments

#: the top level's names -> their home module, imported when first used, so that the command
#: line's help (``torchjfa --help``) needs neither torch nor the flow
_HOMES = {
    "estimators": None, "physical": None, "robots": None,
    "InverseDynamics": "dynamics", "ParameterLayout": "dynamics", "RigidBodyModel": "dynamics",
    "BayesianJFA": "estimators", "Identification": "identification",
    "Options": "identification", "identify": "identification",
    "Moments": "stats", "kfold_moments": "stats",
}  # fmt: skip
__all__ = list(_HOMES)


def __getattr__(name: str):
    from importlib import import_module
    from importlib.util import find_spec

    if name not in _HOMES:
        # a subpackage or module (``torchjfa.sim``, ``torchjfa.io``, ...), as after ``import``
        if name.startswith("__") or find_spec(f"{__name__}.{name}") is None:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        return import_module(f"{__name__}.{name}")
    home = _HOMES[name]
    value = import_module(f"{__name__}.{name if home is None else home}")
    if home is not None:
        value = getattr(value, name)
    globals()[name] = value  # once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOMES))


__version__ = "0.1.0"
