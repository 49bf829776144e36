"""A report a person can read: is the identified model good, what to do next, and the numbers
behind that.

`make_report` takes an `IdentificationResult` (the fitted estimate, also
re-exported by `torchjfa.identification`) and held-out data and measures what a user needs
before putting the identified model in a controller:

* the verdict (`IdentificationReport.judge`): the held-out torque error against the
  description's, physical consistency, how many parameters the data do not determine, the
  warnings, and the next step, by rules on these numbers (`torchjfa.report.Verdict`);
* held-out torque nMSE and RMS error per joint for the identified model, the unconstrained
  estimate and the description's parameters;
* per parameter: what the data determine (`torchjfa.physical.base_parameters`), the consistent
  (projected) value and what fixes it (data, description prior, projection), the estimator's
  unconstrained value, its delete-one-block jackknife spread (Bayesian JFA's posterior
  standard deviation and relevance too, in ``report.json`` and ``parameters.csv`` only: neither
  measures the error), and the description's (CAD) value;
* the physical-consistency check (`torchjfa.physical.check`) of both estimates;
* noise: the estimator's output noise and, with a periodic excitation, the spread between
  periods of positions, velocities, accelerations and torques.

`IdentificationReport.write` puts it in a folder: ``model.npz`` (`torchjfa.io.load_identified`
reads it), ``validation.npz`` (the held-out q, qd, qdd, tau the figures were computed on),
``parameters.csv``, ``report.json``, ``report.md`` (short; ``appendix=True`` adds the long
tables) and the PNG figures.
"""

from ._legged import legged_markdown as legged_markdown
from ._legged import write_legged as write_legged
from ._report import IdentificationReport as IdentificationReport
from ._report import TorqueFit as TorqueFit
from ._report import make_report as make_report
from ._report import predicted_torques as predicted_torques
from ._report import torque_errors as torque_errors
from ._result import PRIOR_TOLERANCE as PRIOR_TOLERANCE
from ._result import IdentificationResult as IdentificationResult
from ._verdict import Verdict as Verdict
from ._words import UNDETERMINED_FACTOR as UNDETERMINED_FACTOR
from ._words import estimator_text as estimator_text
from ._words import undetermined as undetermined
from ._words import verdict as verdict
