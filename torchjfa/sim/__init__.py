"""Simulated Sarcos-like robots in MuJoCo: models, identification data, controllers.

Use this package to rebuild the paper's robot experiments without the robots, and to simulate
any description: `simulated_robot` compiles a robot with chosen joint effects, `simulate`
records its noisy log (``torchjfa simulate``) and `evaluate_simulated` judges an identified
model on it (``torchjfa evaluate --robot``).
`load_robot` compiles the 7-DoF head or 10-DoF arm with switchable unmodeled effects
(`load_description` compiles any URDF or MJCF description the same way, for the same uses),
`generate_log` records a noisy `SimulatedLog` (a `torchjfa.data.JointLog` plus its ground truth)
of the robot tracking a periodic excitation, and `computed_torque` evaluates identified
parameters in closed loop; `replay` rolls identified (`mujoco_model`) and description
(`description_model`) models out open loop on a real log's measured torques, and `refine` fits
their friction loss, damping, armature and a torque delay to such rollouts with `mujoco.sysid`
(the ``sysid`` extra), keeping what held-out rollouts confirm. `regressor_noise` and
`PeriodNoise` (the noise from the repeated periods) live in `torchjfa.data` and are
re-exported here; `load_log` reads a `SimulatedLog` file as one and any other log file as a
`torchjfa.data.JointLog`. `simulate_legged` records a legged robot (a floating base, feet on
the ground) standing and swaying its body, with its feet's contact wrenches
(`SimulatedLeggedLog`, a `torchjfa.data.LeggedLog` with its truth).
"""

from ..data import PeriodNoise as PeriodNoise
from ..data import regressor_noise as regressor_noise
from ._control import ControlResult as ControlResult
from ._control import computed_torque as computed_torque
from ._control import evaluate_control as evaluate_control
from ._description import Description as Description
from ._description import DescriptionError as DescriptionError
from ._description import load_description as load_description
from ._generate import DEFAULT_N_SAMPLES as DEFAULT_N_SAMPLES
from ._generate import DEFAULT_RATE as DEFAULT_RATE
from ._generate import DEFAULT_RATES as DEFAULT_RATES
from ._generate import generate_log as generate_log
from ._legged import LEGGED_NOISE as LEGGED_NOISE
from ._legged import SimulatedLeggedLog as SimulatedLeggedLog
from ._legged import simulate_legged as simulate_legged
from ._log import SensorNoise as SensorNoise
from ._log import SimulatedLog as SimulatedLog
from ._log import load_log as load_log
from ._refine import Refinement as Refinement
from ._refine import refine as refine
from ._replay import HORIZONS as HORIZONS
from ._replay import Replay as Replay
from ._replay import description_model as description_model
from ._replay import mujoco_model as mujoco_model
from ._replay import offset_torques as offset_torques
from ._replay import replay as replay
from ._robots import EFFECTS as EFFECTS
from ._robots import ROBOTS as ROBOTS
from ._robots import UNMODELED as UNMODELED
from ._robots import load_robot as load_robot
from ._robots import model_path as model_path
from ._robots import robot_effects as robot_effects
from ._robots import set_effects as set_effects
from ._robots import true_parameters as true_parameters
from ._simulate import DEFAULT_TEST_SAMPLES as DEFAULT_TEST_SAMPLES
from ._simulate import SimulatedEvaluation as SimulatedEvaluation
from ._simulate import SimulatedRobot as SimulatedRobot
from ._simulate import check_trajectory as check_trajectory
from ._simulate import evaluate_simulated as evaluate_simulated
from ._simulate import limit_warnings as limit_warnings
from ._simulate import simulate as simulate
from ._simulate import simulated_robot as simulated_robot
from ._trajectory import SinusoidTrajectory as SinusoidTrajectory
from ._trajectory import random_trajectory as random_trajectory
