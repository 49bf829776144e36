"""torchjfa: probabilistic system identification of robots in PyTorch.

The flow: a robot description (URDF/MJCF) gives a `RigidBodyModel`, whose batched regressor
turns joint logs into `Moments`; an estimator (Bayesian joint factor analysis regression or a
baseline) fits parameters from the moments; the projection makes them physically consistent;
`InverseDynamics` returns the identified model as an ``nn.Module``.
"""

from .stats import Moments as Moments
from .stats import kfold_moments as kfold_moments

__version__ = "0.1.0"
