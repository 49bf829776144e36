"""torchjfa: probabilistic system identification of robots in PyTorch.

The flow: a robot description (URDF/MJCF) gives a `RigidBodyModel`, whose batched regressor
turns joint logs into `Moments`; an estimator (Bayesian joint factor analysis regression or a
baseline, `torchjfa.estimators`) fits parameters from the moments; `torchjfa.physical.project`
makes them physically consistent; `InverseDynamics` returns the identified model as an
``nn.Module``. `torchjfa.sim` simulates robots in MuJoCo and evaluates identified models.
"""

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

__version__ = "0.1.0"
