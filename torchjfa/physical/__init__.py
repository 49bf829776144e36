"""Physically consistent parameters: parametrisations, projection and consistency checks.

- `VirtualParameters` (the paper's eq. 5) and `LogCholeskyParameters` (Rucker and Wensing,
  2022): ``nn.Module`` s whose output theta is consistent for every value of their variables.
  They and `check` are defined beside the parameter layout in `torchjfa.dynamics` (whose
  `InverseDynamics` trains through them) and are re-exported here.
- `project`: the consistent theta closest to an unconstrained estimate in the data's metric
  ``X^T X + N diag(input noise)`` (eq. 8): the convex problem's optimum from a semidefinite
  solver, polished by LBFGS on either parametrisation; `project_convex` the convex problem
  alone (cvxpy, Clarabel) and `certify` the comparison; `unconstrained_projection` the same
  objective's minimiser without the constraints.
- `check`: per-body mass, inertia, triangle-inequality, pseudo-inertia and friction checks.
- `base_parameters`: what the data determine (base parameters, their combinations, the
  condition number, and per parameter: determined, in combination, poorly or not excited).
"""

from ..dynamics._consistency import ConsistencyReport as ConsistencyReport
from ..dynamics._consistency import check as check
from ..dynamics._parametrizations import LogCholeskyParameters as LogCholeskyParameters
from ..dynamics._parametrizations import VirtualParameters as VirtualParameters
from ..dynamics._parametrizations import inertial_from_log_cholesky as inertial_from_log_cholesky
from ..dynamics._parametrizations import (
    inertial_from_pseudo_inertia as inertial_from_pseudo_inertia,
)
from ..dynamics._parametrizations import inertial_from_virtual as inertial_from_virtual
from ._base import BaseParameters as BaseParameters
from ._base import base_parameters as base_parameters
from ._base import parameter_scales as parameter_scales
from ._convex import ConvexProjection as ConvexProjection
from ._convex import certify as certify
from ._convex import project_convex as project_convex
from ._objective import DEFAULT_PARAMETRIZATION as DEFAULT_PARAMETRIZATION
from ._project import PARAMETRIZATIONS as PARAMETRIZATIONS
from ._project import ProjectionResult as ProjectionResult
from ._project import project as project
from ._project import unconstrained_projection as unconstrained_projection
