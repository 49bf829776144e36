"""torchjfa.data: joint logs from files, and their preparation for identification.

`JointLog` is the one log type (a `torchjfa.sim.SimulatedLog` is a `JointLog` plus its ground
truth). `read_log` reads CSV, NPZ and Parquet logs and ROS bags into one (torques, or motor
currents with drive gains; time in s, ms, us or ns); `prepare` resamples, filters,
differentiates, trims and decimates it; `choose_cutoff` picks its filter's cut-off from the
data, `armature_helps` whether the motors' armature predicts better, and `coupled_drives`
which consecutive joints a motor turning both (a drive train the model lacks) would explain;
`differentiate` is the filter and derivatives alone, `edge_seconds` its reach at a log's
ends;
`motion_span` finds the standing still at a log's ends;
`check_log` finds logs that cannot identify anything (gaps, no motion, degrees, velocities in
deg/s, scrambled columns); `coverage` says where another log's motion goes beyond the
identification log's;
`regressor_noise` estimates the regression's input and output noise from repeated excitation
periods; `signal_noise` estimates the sensors' noise from a raw log's spectrum and
`propagated_noise` pushes it through the preparation and the regressor to the same noise for
any log. `NpzArchive` and `NpzLog` are the one ``.npz`` reader (member by member, row range by
row range); `log_sources` streams logs to `torchjfa.identification.stream_moments` through it.
`LeggedLog` is a legged robot's log (a floating base, joints, contacts): `read_legged_log`
reads it, `prepare_legged` filters and differentiates it.
"""

from ._checks import LogProblem as LogProblem
from ._checks import check_log as check_log
from ._columns import SPIKE_RANGE as SPIKE_RANGE
from ._columns import SPIKE_STEPS as SPIKE_STEPS
from ._columns import spike_rows as spike_rows
from ._coupling import CoupledDrive as CoupledDrive
from ._coupling import coupled_drives as coupled_drives
from ._coverage import DEFAULT_COVERAGE_LIMIT as DEFAULT_COVERAGE_LIMIT
from ._coverage import Coverage as Coverage
from ._coverage import coverage as coverage
from ._cutoff import COULOMB_GRID as COULOMB_GRID
from ._cutoff import CutoffChoice as CutoffChoice
from ._cutoff import armature_helps as armature_helps
from ._cutoff import choose_cutoff as choose_cutoff
from ._cutoff import cutoff_grid as cutoff_grid
from ._differentiate import DEFAULT_CUTOFF_HZ as DEFAULT_CUTOFF_HZ
from ._differentiate import EDGE_PERIODS as EDGE_PERIODS
from ._differentiate import Derivatives as Derivatives
from ._differentiate import differentiate as differentiate
from ._differentiate import edge_seconds as edge_seconds
from ._differentiate import savgol_window as savgol_window
from ._legged import BASE_POSE as BASE_POSE
from ._legged import BASE_TWIST as BASE_TWIST
from ._legged import IMU_COLUMNS as IMU_COLUMNS
from ._legged import LeggedLog as LeggedLog
from ._legged import prepare_legged as prepare_legged
from ._legged import read_legged_log as read_legged_log
from ._log import JointLog as JointLog
from ._log import read_log as read_log
from ._log import write_log as write_log
from ._npz import NpzArchive as NpzArchive
from ._npz import NpzLog as NpzLog
from ._periods import PeriodNoise as PeriodNoise
from ._periods import regressor_noise as regressor_noise
from ._prepare import detect_period as detect_period
from ._prepare import is_uniform as is_uniform
from ._prepare import prepare as prepare
from ._prepare import resample as resample
from ._prepare import transient_periods as transient_periods
from ._propagate import PropagatedNoise as PropagatedNoise
from ._propagate import propagated_noise as propagated_noise
from ._propagate import redrawn_logs as redrawn_logs
from ._rest import RestSpan as RestSpan
from ._rest import motion_span as motion_span
from ._schema import KINDS as KINDS
from ._schema import TIME_COLUMN as TIME_COLUMN
from ._schema import LogError as LogError
from ._sources import log_length as log_length
from ._sources import log_sources as log_sources
from ._spectrum import SignalNoise as SignalNoise
from ._spectrum import floor_variance as floor_variance
from ._spectrum import signal_noise as signal_noise
