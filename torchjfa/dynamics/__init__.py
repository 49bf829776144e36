"""Rigid-body models from URDF/MJCF: forward kinematics, the batched dynamics regressor,
`InverseDynamics`, forward dynamics (mass matrix, accelerations, rollouts) and drive trains
(`Transmission`: motors that turn joints through gearboxes, coupled or not)."""

from ._floating import FloatingBaseModel as FloatingBaseModel
from ._forward import bias_forces as bias_forces
from ._forward import forward_dynamics as forward_dynamics
from ._forward import mass_matrix as mass_matrix
from ._forward import rollout as rollout
from ._inverse_dynamics import ConsistentTheta as ConsistentTheta
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
from ._transmission import Transmission as Transmission
from ._transmission import read_transmission as read_transmission
from ._writeback import write_mjcf as write_mjcf
from ._writeback import write_urdf as write_urdf
