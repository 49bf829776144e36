"""Rigid-body models from URDF/MJCF: forward kinematics, the batched dynamics regressor and
`InverseDynamics`."""

from ._inverse_dynamics import InverseDynamics as InverseDynamics
from ._model import BodyInertial as BodyInertial
from ._model import RigidBodyModel as RigidBodyModel
from ._parameters import FRICTION_KINDS as FRICTION_KINDS
from ._parameters import INERTIAL_NAMES as INERTIAL_NAMES
from ._parameters import ParameterLayout as ParameterLayout
from ._parameters import inertia_about_origin as inertia_about_origin
from ._parameters import inertial_from_vector as inertial_from_vector
from ._parameters import inertial_vector as inertial_vector
from ._parameters import pseudo_inertia as pseudo_inertia
