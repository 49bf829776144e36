"""torchjfa.identification: a robot identified from its raw log, as one call or stage by stage.

`identify` (also `torchjfa.identify`) runs the whole flow with `Options`, whose defaults are
chosen for real robots; the ``torchjfa identify`` command is that call. The stages, in order,
each taking the previous one's output:

1. `load_model`: the `RigidBodyModel` from a URDF / MJCF file or a robot's name;
2. `read`: the raw log as a `torchjfa.data.JointLog`, checked (`RawLog`);
3. `prepare_data`: cut-off, filter, derivatives, the held-out part (`PreparedData`);
4. `choose_noise`: joint weights and the regressor's input noise (`NoiseChoice`);
5. `fit`: moments, estimator, bias correction (`simex_bias`), projection
   (`torchjfa.pipeline.identify`;
   `torchjfa.pipeline.IdentificationResult`);
6. `validate`: the report on the held-out data (`torchjfa.report.IdentificationReport`).

`signal_bootstrap` refits on re-drawn sensor noise for the spread of the unconstrained estimate;
`simex_bias` takes the sensor noise's bias of the estimate from the same refits.
"""

from ._bootstrap import signal_bootstrap as signal_bootstrap
from ._bootstrap import simex_bias as simex_bias
from ._identify import Identification as Identification
from ._identify import identify as identify
from ._options import AUTO_BIAS_REFITS as AUTO_BIAS_REFITS
from ._options import JOINT_TERMS as JOINT_TERMS
from ._options import Compute as Compute
from ._options import IdentificationError as IdentificationError
from ._options import IdentificationWarning as IdentificationWarning
from ._options import Options as Options
from ._options import joint_terms as joint_terms
from ._stages import NoiseChoice as NoiseChoice
from ._stages import PreparedData as PreparedData
from ._stages import RawLog as RawLog
from ._stages import cap_period_noise as cap_period_noise
from ._stages import choose_noise as choose_noise
from ._stages import coverage_warnings as coverage_warnings
from ._stages import fit as fit
from ._stages import load_model as load_model
from ._stages import make_estimator as make_estimator
from ._stages import prepare_data as prepare_data
from ._stages import read as read
from ._stages import validate as validate
