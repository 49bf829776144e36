"""Optimal excitation trajectories for identification, designed before the log exists.

Use this package to choose the motion a robot runs for identification: `limits_from_model`
collects the limits (description and user; by default with margins, an acceleration limit, the
mounting plane and self-collision), `optimize_excitation` optimises a periodic Fourier series
(`FourierTrajectory`, at rest at a posture at the start of every period) for the D-optimality,
condition number or E-optimality of the base-parameter information matrix, through the batched
regressor with torch autograd, and checks every constraint on a fine grid (`check_limits`;
`physical_margins` says what is left of each, in physical units); `random_excitation` is the
library's random sum of sinusoids in the same limits, the baseline; `design_excitation` runs
both and `ExcitationDesign.write` writes the trajectory, its report and figures (``torchjfa
excite`` is that call); `FourierTrajectory.to_sinusoid` hands the result to `torchjfa.sim.generate_log`.
"""

from ._check import check_limits as check_limits
from ._check import physical_margins as physical_margins
from ._design import DEFAULT_RATE as DEFAULT_RATE
from ._design import ExcitationResult as ExcitationResult
from ._design import optimize_excitation as optimize_excitation
from ._design import random_excitation as random_excitation
from ._fourier import FourierTrajectory as FourierTrajectory
from ._fourier import constrain_coefficients as constrain_coefficients
from ._fourier import fourier_states as fourier_states
from ._information import CRITERIA as CRITERIA
from ._information import base_directions as base_directions
from ._information import criterion_value as criterion_value
from ._information import information_matrix as information_matrix
from ._information import soft_condition as soft_condition
from ._information import trajectory_information as trajectory_information
from ._limits import Limits as Limits
from ._limits import WorkspaceBox as WorkspaceBox
from ._limits import constraint_violations as constraint_violations
from ._limits import limits_from_model as limits_from_model
from ._report import ExcitationDesign as ExcitationDesign
from ._report import design_excitation as design_excitation
