"""How an identification runs: `Options` (every choice of the flow) and `Compute` (where and how
the pass over the data runs)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace

import torch

from ..dynamics import FRICTION_KINDS

__all__ = [
    "Compute",
    "Options",
    "IdentificationError",
    "IdentificationWarning",
    "JOINT_TERMS",
    "joint_terms",
]

#: the joint terms `Options.friction` takes: friction, and the motor's reflected inertia
JOINT_TERMS = FRICTION_KINDS


class IdentificationError(ValueError):
    """The data or the options cannot give an identification: what is wrong, and what to do.

    (The command line prints it as one line and exits with status 2.)"""


class IdentificationWarning(UserWarning):
    """The identification ran but something in it needs the user's attention."""


#: the bias correction's refits with ``bias_correction="auto"`` for least squares
AUTO_BIAS_REFITS = 20


@dataclass(frozen=True)
class Compute:
    """Where and how the pass over the data runs (`torchjfa.pipeline.stream_moments`).

    Attributes:
        chunk_size: samples per regressor chunk; memory ``O(chunk_size * n_dof * n_params)``.
        device: where the regressor, moments and fits are computed (None: CPU).
        distributed: share the pass between the processes of an initialised
            ``torch.distributed`` group; every process gets the same result.
        group: that process group (None: the default group).
        progress: show progress bars.
        compiled: the regressor's path: None the C++ kernel where a compiler is found, True
            insists on it, False the torch path (`RigidBodyModel.regressor`).
    """

    chunk_size: int = 4096
    device: torch.device | str | None = None
    distributed: bool = False
    group: object = None
    progress: bool = False
    compiled: bool | None = None

    def stream(self) -> dict[str, object]:
        """The keywords of `stream_moments` / `torchjfa.pipeline.identify` this sets."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class Options:
    """Every choice of `torchjfa.identify`, with defaults that work on a real robot's log
    (docs/real-robot.md measures them on a Franka Panda). The command line's options are these.

    Robot:
        friction: the joint terms of the model when the robot is given by name or file,
            from `JOINT_TERMS` (viscous, Coulomb and offset friction; ``"armature"``).

    Reading (`torchjfa.data.read_log`):
        columns: the library's column names -> the log's (``{"t": "time", ...}``), or None.
        time_scale: seconds per unit of the log's time column (1e-9 for ns).
        drop_nan: drop rows holding NaN instead of stopping.
        max_seconds: use only the first this many seconds of the log (a quick check), or None.

    Preparation (`torchjfa.data.prepare`):
        cutoff: the zero-phase low-pass cut-off, Hz, or ``"auto"``
            (`torchjfa.data.choose_cutoff` on the training part of the log).
        coulomb_velocity: the Coulomb term's smoothing velocity ``v_c``, rad/s (its column
            ``tanh(qd / v_c)``; 0 is ``sign(qd)``), or ``"auto"``: chosen with the cut-off
            from `torchjfa.data.COULOMB_GRID` by the same held-out prediction (at a given
            cut-off, by that cut-off alone). Without a Coulomb term it does nothing.
        filter: ``"butterworth"`` (order 4) or ``"savgol"``.
        velocity: ``"auto"``, ``"measured"`` or ``"differentiate"``.
        period: the excitation period, s, ``"auto"`` (detect) or None (none).
        skip_start: seconds of start-up transient to drop, or ``"auto"`` (needs a period).
        decimate: keep every k-th sample after filtering.
        validation: the fraction held out at the end of the log (unless a validation log is
            given), with a gap of the filter's reach between the parts.

    Estimation:
        estimator: a name of `torchjfa.estimators.available` (`torchjfa.estimators.make`: the
            library's and any registered one) or an estimator
            with ``fit_intercept=False``, used as it is.
        estimator_options: keywords of the named estimator (e.g. ``{"max_iter": 20000}``).
        weighting: ``"residual"`` (each joint's equations weighted by its inverse residual
            variance, `torchjfa.pipeline.residual_joint_weights`) or ``"none"``.
        input_noise: the regressor's input noise: ``"auto"`` (from the repeated excitation
            periods where the training data hold two or more, else ``"propagated"`` for an
            estimator that takes an input noise and none for the others),
            ``"periods"`` (insist on it), ``"propagated"`` (the raw log's sensor noise, from
            its spectrum, pushed through the preparation and the regressor:
            `torchjfa.data.propagated_noise`), ``"learn"`` (none given: Bayesian JFA learns
            it), or ``(n_params,)`` variances of the (weighted) regressor columns.
        jackknife: blocks of the delete-one-block jackknife spread (0: none).
        bias_correction: refits on the raw log with re-drawn sensor noise for the
            errors-in-variables bias of the unconstrained estimate, subtracted before the
            projection (`torchjfa.identification.simex_bias`; 0: no correction), or ``"auto"``:
            `AUTO_BIAS_REFITS` for least squares (OLS), none for the other estimators (the
            shrinkage and relevance pruning of Bayesian JFA, ridge, lasso... change with the
            noise level, so the linear extrapolation does not hold for them: on the simulated
            head, Bayesian JFA's correction was as large as the estimate; `bias_refits`).

    Projection (`torchjfa.physical.project`):
        project: project onto physically consistent parameters.
        parametrization: ``"log-cholesky"`` (fully consistent) or ``"virtual"`` (eq. 5).
        description_prior: ``"auto"`` (default), a weight >= 0 or None (no prior; see
            `torchjfa.pipeline.identify`): the projection is pulled towards the description's
            parameters where the data are silent, with a weight chosen by cross-validation
            over the training blocks (``"auto"``). With ``project=False`` there is no
            projection and ``"auto"`` does nothing. On the real Panda log
            (``scripts/real_panda.py``) it kept every link mass within 0.70-1.05x of the
            description's (three were outside [0.3x, 3x] without it), lowered the held-out
            mean RMS by 1.5 % and raised the mean nMSE by 9 % (joints 5-7 lost, joint 2
            gained; docs/real-robot.md). In simulation, where the description is the truth,
            the scripts turn it off (``description_prior=None``): it would lend them the
            answer.
        projection_options: more keywords of `torchjfa.physical.project`.

    compute: `Compute` (chunking, device, processes, progress, the regressor's path).
    """

    friction: tuple[str, ...] = ("viscous", "coulomb", "offset")
    columns: Mapping[str, str] | None = None
    time_scale: float = 1.0
    drop_nan: bool = False
    max_seconds: float | None = None
    cutoff: float | str = "auto"
    coulomb_velocity: float | str = "auto"
    filter: str = "butterworth"
    velocity: str = "auto"
    period: float | str | None = "auto"
    skip_start: float | str = 0.0
    decimate: int = 1
    validation: float = 0.2
    estimator: object = "ols"
    estimator_options: Mapping[str, object] = field(default_factory=dict)
    weighting: str = "residual"
    input_noise: object = "auto"
    jackknife: int = 20
    bias_correction: int | str = "auto"
    project: bool = True
    parametrization: str = "log-cholesky"
    description_prior: float | str | None = "auto"
    projection_options: Mapping[str, object] = field(default_factory=dict)
    compute: Compute = field(default_factory=Compute)

    def __post_init__(self) -> None:
        object.__setattr__(self, "friction", joint_terms(self.friction))
        _choice("filter", self.filter, ("butterworth", "savgol"))
        _choice("velocity", self.velocity, ("auto", "measured", "differentiate"))
        _choice("weighting", self.weighting, ("residual", "none"))
        _choice("parametrization", self.parametrization, ("log-cholesky", "virtual"))
        if isinstance(self.estimator, str):
            from ..estimators import available

            _choice("estimator", self.estimator, available())
        if isinstance(self.input_noise, str):
            _choice("input_noise", self.input_noise, ("auto", "learn", "periods", "propagated"))
        if self.cutoff != "auto" and not 0 < _number(self.cutoff) < float("inf"):
            raise IdentificationError(
                f"cutoff must be 'auto' or a positive Hz, got {self.cutoff!r}"
            )
        if self.coulomb_velocity != "auto" and not 0 <= _number(self.coulomb_velocity) < float(
            "inf"
        ):
            raise IdentificationError(
                "coulomb_velocity must be 'auto' or a number >= 0, rad/s, got "
                f"{self.coulomb_velocity!r}"
            )
        if not 0.0 < _number(self.validation) < 1.0:
            raise IdentificationError(
                f"validation must be a fraction in (0, 1), got {self.validation}"
            )
        n = self.bias_correction
        if n != "auto" and (isinstance(n, bool) or not isinstance(n, int) or n == 1 or n < 0):
            raise IdentificationError(
                f"bias_correction must be 'auto', 0 (off) or at least 2 refits, got {n!r}"
            )
        if self.description_prior not in (None, "auto") and not self.project:
            raise IdentificationError(
                "the description prior acts in the projection: it needs project=True"
            )

    def bias_refits(self, estimator) -> int:
        """How many refits the bias correction makes for ``estimator`` (0: none)."""
        if self.bias_correction != "auto":
            return int(self.bias_correction)
        from ..estimators import OLS

        return AUTO_BIAS_REFITS if type(estimator) is OLS else 0

    def replace(self, **changes) -> Options:
        """A copy with ``changes`` (``Options`` is frozen)."""
        return replace(self, **changes)


def joint_terms(value) -> tuple[str, ...]:
    """Joint terms from `JOINT_TERMS`, given as a sequence or as the command line writes them
    (``"viscous,coulomb"``; ``"none"`` or ``""`` for none), checked.

    Raises:
        IdentificationError: on a term that is not one of `JOINT_TERMS`.
    """
    if isinstance(value, str):
        text = value.strip()
        value = () if text.lower() in ("", "none") else [k.strip() for k in text.split(",")]
    terms = tuple(k for k in value if k)
    bad = [k for k in terms if k not in JOINT_TERMS]
    if bad:
        raise IdentificationError(f"unknown joint term(s) {bad}; choose from {JOINT_TERMS}")
    return terms


def _number(value) -> float:
    """``value`` as a float, NaN where it is not a number (so that the range checks refuse it)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _choice(name: str, value, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise IdentificationError(f"{name} must be one of {allowed}, got {value!r}")
