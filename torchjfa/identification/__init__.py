"""torchjfa.identification: a robot identified from its logs, as one call or stage by stage.

`identify` (also `torchjfa.identify`) runs the whole flow with `Options`, whose defaults are
chosen for real robots; the ``torchjfa identify`` command is that call, its flags generated
from `Options`' fields. The stages, in order, each taking the previous one's output:

1. `load_model`: the `RigidBodyModel` from a URDF / MJCF file or a robot's name;
2. `read`: a raw log as a `torchjfa.data.JointLog`, checked (`RawLog`); one per log;
3. `prepare_data`: the rest at the logs' ends dropped, the cut-off, filter, derivatives and
   the held-out part of each log (`PreparedData`, one `LogPart` per log);
4. `choose_noise`: joint weights and the regressor's input noise (`NoiseChoice`);
5. `fit`: the training data's moments, the estimator and its jackknife
   (`IdentificationResult`); it also takes prepared logs (simulated ones, say) directly;
6. `correct_bias`: the sensor noise's bias of the unconstrained estimate (`simex_bias`);
7. `make_consistent`: the projection onto physically consistent parameters, with the
   description as a prior where the data are silent;
8. `validate`: the report on the held-out data (`torchjfa.report.IdentificationReport`).

`stream_moments` (the logs' `Moments`, streamed through the regressor) and
`residual_joint_weights` are the building blocks of `fit` and `choose_noise`, for fitting
several estimators on the same data; `signal_bootstrap` refits on re-drawn sensor noise for the
spread of the unconstrained estimate. `evaluate` judges an identified model on other logs
(``torchjfa evaluate``), against the measured torque as `validate` does (`measured_torque`);
`identify_payload` identifies a body fixed to a link (``torchjfa payload``);
`identify_drive_gains` the per-joint drive gains from a payload of known mass (``torchjfa
payload --mass``). `contact_equations` gives the regression rows of a floating-base robot
(`torchjfa.dynamics.FloatingBaseModel`) in contact: with measured contact wrenches, the base
rows alone, or the contact forces projected out.
"""

from ..report._result import IdentificationResult as IdentificationResult
from ._bias import correct_bias as correct_bias
from ._bias import signal_bootstrap as signal_bootstrap
from ._bias import simex_bias as simex_bias
from ._consistent import make_consistent as make_consistent
from ._contacts import RowMoments as RowMoments
from ._contacts import consistent_floating as consistent_floating
from ._contacts import contact_equations as contact_equations
from ._contacts import contact_moments as contact_moments
from ._contacts import row_moments as row_moments
from ._evaluate import Evaluation as Evaluation
from ._evaluate import evaluate as evaluate
from ._fit import fit as fit
from ._fit import make_estimator as make_estimator
from ._gains import DriveGains as DriveGains
from ._gains import identify_drive_gains as identify_drive_gains
from ._identify import Identification as Identification
from ._identify import identify as identify
from ._legged import LeggedIdentification as LeggedIdentification
from ._legged import identify_legged as identify_legged
from ._legged_eval import LeggedEvaluation as LeggedEvaluation
from ._legged_eval import evaluate_legged as evaluate_legged
from ._noise import NoiseChoice as NoiseChoice
from ._noise import cap_period_noise as cap_period_noise
from ._noise import choose_noise as choose_noise
from ._options import AUTO_BIAS_REFITS as AUTO_BIAS_REFITS
from ._options import DEFAULT_JOINT_TERMS as DEFAULT_JOINT_TERMS
from ._options import JOINT_TERMS as JOINT_TERMS
from ._options import Compute as Compute
from ._options import IdentificationError as IdentificationError
from ._options import IdentificationWarning as IdentificationWarning
from ._options import Options as Options
from ._options import joint_terms as joint_terms
from ._payload import Payload as Payload
from ._payload import identify_payload as identify_payload
from ._prepare import LogPart as LogPart
from ._prepare import PreparedData as PreparedData
from ._prepare import prepare_data as prepare_data
from ._prior import PRIOR_BLOCKS as PRIOR_BLOCKS
from ._prior import PRIOR_TOLERANCE as PRIOR_TOLERANCE
from ._prior import PRIOR_WEIGHTS as PRIOR_WEIGHTS
from ._prior import description_problems as description_problems
from ._read import RawLog as RawLog
from ._read import load_model as load_model
from ._read import read as read
from ._stream import residual_joint_weights as residual_joint_weights
from ._stream import stream_moments as stream_moments
from ._validate import HELD_OUT_TARGET as HELD_OUT_TARGET
from ._validate import coverage_warnings as coverage_warnings
from ._validate import measured_torque as measured_torque
from ._validate import validate as validate
