"""How an identification runs: `Options` (every choice of the flow) and `Compute` (where and how
the pass over the data runs).

Each field carries its command-line flag, help text, choices and argument parser in its
metadata (`option`), so that ``torchjfa identify``'s options are generated from these
dataclasses and cannot drift from them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import Field, dataclass, fields, replace
from typing import TYPE_CHECKING

import torch

from ..data import COULOMB_GRID, DEFAULT_CUTOFF_HZ
from ..dynamics import FRICTION_KINDS, read_transmission
from ..physical import DEFAULT_PARAMETRIZATION
from ..stats import CHUNK_SIZE
from . import _parse as parse
from ._errors import IdentificationError, IdentificationWarning
from ._option_checks import (
    check_estimator_options,
    check_numbers,
    check_reading,
    choice,
    frame_names,
)
from ._option_field import GROUPS, option

if TYPE_CHECKING:
    from ..estimators import LinearEstimator

__all__ = [
    "AUTO_BIAS_REFITS",
    "Compute",
    "DEFAULT_JOINT_TERMS",
    "GROUPS",
    "IdentificationError",
    "IdentificationWarning",
    "JOINT_TERMS",
    "Options",
    "joint_terms",
    "option",
]

#: the joint terms `Options.friction` takes: friction, and the motor's reflected inertia
JOINT_TERMS = FRICTION_KINDS
#: the joint terms of a model read from a file or a name when `Options.friction` is None
DEFAULT_JOINT_TERMS = ("viscous", "coulomb", "offset")
#: the bias correction's refits with ``bias_correction="auto"`` for least squares
AUTO_BIAS_REFITS = 20


# ------------------------------------------------------------------------------ parsers
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


def _estimators() -> tuple[str, ...]:
    from ..estimators import available

    return available()


# ------------------------------------------------------------------------------ Compute
@dataclass(frozen=True)
class Compute:
    """Where and how the pass over the data runs (`torchjfa.identification.stream_moments`).

    Attributes:
        chunk_size: samples per regressor chunk; memory ``O(chunk_size * n_dof * n_params)``.
        device: where the regressor, moments and fits are computed (None: CPU).
        distributed: share the pass between the processes of an initialised
            ``torch.distributed`` group; every process gets the same result.
        group: that process group (None: the default group).
        progress: show progress bars (the command shows them unless ``--quiet``).
        compiled: the regressor's path: None the C++ kernel where a compiler is found, True
            insists on it, False the torch path (`RigidBodyModel.regressor`).
    """

    chunk_size: int = option(
        CHUNK_SIZE, group="compute", help="samples per regressor chunk (memory grows with it)"
    )
    device: torch.device | str | None = option(
        None, group="compute", parse=str, help="where to compute, e.g. cuda (default: CPU)"
    )
    distributed: bool = option(False, group="compute", cli=False, help="")
    group: object = option(None, group="compute", cli=False, help="")
    progress: bool = option(False, group="compute", cli=False, help="")
    compiled: bool | None = option(
        None,
        group="compute",
        action="switch",
        help="form the regressor with a C++ kernel generated for the robot (several times "
        "faster; built once per robot and cached); by default wherever a C++ compiler is "
        "found, else the torch path",
    )

    def stream(self) -> dict[str, object]:
        """The keywords of `torchjfa.identification.stream_moments` this sets."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


# ------------------------------------------------------------------------------ Options
@dataclass(frozen=True)
class Options:
    """Every choice of `torchjfa.identify`, with defaults that work on real robots' logs. The
    ``torchjfa identify`` command's options are these fields (`GROUPS`; each field's metadata
    holds its flag and help).

    Reading (`torchjfa.data.read_log`):
        columns: the library's column names -> the log's (``{"t": "time", ...}``, or
            patterns: ``{"q_{joint}": "pos_{joint}"}``), or None.
        time_scale: seconds per unit of the log's time column (1e-9 for ns), or None: seconds,
            with milliseconds, microseconds and nanoseconds recognised from the sampling rate
            (the report says so).
        drop_nan: drop rows holding NaN instead of stopping.
        drop_outliers: drop rows holding an isolated spike instead of stopping
            (`torchjfa.data.spike_rows`).
        drop_cut_line: leave out a text log's last line cut while it was written instead of
            stopping.
        max_seconds: use only the first this many seconds of each log (a quick check), or None.
        drive_gains: N m/A per joint, to turn motor-current columns ``i_<joint>`` (A) into
            joint torques: a sequence in the robot's joint order or ``{joint: gain}``; None for
            logs of joint torques.
        topic: the ``sensor_msgs/JointState`` topic of a ROS bag (default: the only one).
        effort: what a ROS bag's ``effort`` holds: ``"torque"`` (N m) or ``"current"`` (A,
            with ``drive_gains``).

    Preparation (`torchjfa.data.prepare`):
        cutoff: the zero-phase low-pass cut-off, Hz, or ``"auto"``
            (`torchjfa.data.choose_cutoff` on the training part of the log).
        filter: ``"butterworth"`` (order 4) or ``"savgol"``.
        velocity: ``"auto"``, ``"measured"`` or ``"differentiate"``.
        period: the excitation period, s, ``"auto"`` (detect) or None (none).
        skip_start: seconds of start-up transient to drop, or ``"auto"`` (needs a period).
        decimate: keep every k-th sample after filtering.
        validation: the fraction held out at the end of each log (unless validation logs are
            given), with a gap of the filter's reach between the parts.
        trim_rest: drop the standing still at the start and end of each log
            (`torchjfa.data.motion_span`), keeping the filter's reach of it.

    The model's joint terms:
        friction: the joint terms (`JOINT_TERMS`: viscous, Coulomb and offset friction;
            ``"armature"``, the motor's reflected inertia); None: `DEFAULT_JOINT_TERMS` for a
            robot given by file or name, the model's own for a `RigidBodyModel` (whose terms
            a different tuple contradicts: an error), and the armature as ``armature`` says.
        coulomb_velocity: the Coulomb term's smoothing velocity ``v_c``, rad/s (its column
            ``tanh(qd / v_c)``; 0 is ``sign(qd)``), or ``"auto"``: chosen with the cut-off
            from `torchjfa.data.COULOMB_GRID` by the same held-out prediction.
        armature: ``"auto"``: with ``friction=None``, the motor's reflected inertia is added
            where it predicts held-out torques within the training part better than without,
            by more than a standard error (`torchjfa.data.armature_helps`); ``"off"``: not.
        fixed_joints: joints of the description held at q = 0 and treated as fixed (a gripper's
            fingers, a mimic joint), for a robot given by file or name.
        transmission: the drive train (`torchjfa.dynamics.Transmission`, a JSON/YAML file of
            one or a mapping): the joint terms then act per motor through the gear ratios,
            coupled ones included, and logs recorded at the motors are converted; None: each
            joint has its own.

    Estimation:
        estimator: a name of `torchjfa.estimators.available` (`torchjfa.estimators.make`: the
            library's and any registered one) or an estimator with ``fit_intercept=False``,
            used as it is.
        estimator_options: keywords of the named estimator (e.g. ``{"max_iter": 20000}``);
            an option the estimator does not take is an error.
        weighting: ``"residual"`` (each joint's equations weighted by its inverse residual
            variance, `torchjfa.identification.residual_joint_weights`) or ``"none"``.
        input_noise: the regressor's input noise: ``"auto"`` (from the repeated excitation
            periods where the training data hold two or more, else ``"propagated"`` for an
            estimator that takes an input noise and none for the others), ``"periods"``
            (insist on it), ``"propagated"`` (the raw log's sensor noise, from its spectrum,
            pushed through the preparation and the regressor:
            `torchjfa.data.propagated_noise`), ``"learn"`` (none given: Bayesian JFA learns
            it), or ``(n_params,)`` variances of the (weighted) regressor columns. For a
            floating base (no periods), ``"auto"`` propagates the base pose's, the joints'
            and the IMU's noise for an estimator that takes it.
        jackknife: blocks of the delete-one-block jackknife spread (0: none).
        bias_correction: refits on the raw log with re-drawn sensor noise for the
            errors-in-variables bias of the unconstrained estimate, subtracted before the
            projection (`torchjfa.identification.correct_bias`; 0: no correction), or
            ``"auto"``: `AUTO_BIAS_REFITS` for least squares (OLS), none for the other
            estimators, whose shrinkage and relevance pruning change with the noise level so
            that the linear extrapolation does not hold for them (`bias_refits`).

    Projection (`torchjfa.physical.project`):
        project: project onto physically consistent parameters.
        parametrization: ``"log-cholesky"`` (fully consistent) or ``"virtual"`` (the paper's
            eq. 5: mass > 0, inertia positive semi-definite).
        description_prior: ``"auto"`` (default), a weight >= 0 or None (no prior): the
            projection is pulled towards the description's parameters where the data are
            silent, with a weight chosen by cross-validation over the training blocks
            (``"auto"``; `torchjfa.identification.make_consistent`). With ``project=False``
            there is no projection and ``"auto"`` does nothing. In simulation, where the
            description is the truth, turn it off: it would lend the fit the answer.
        projection_options: more keywords of `torchjfa.physical.project`.

    Floating-base robots (`torchjfa.identification.identify_legged`):
        floating_base: the robot's root link is a free-flying base (a legged robot, a
            humanoid) and the logs are `torchjfa.data.read_legged_log` logs; None: so where
            the first log has base-pose columns (``base_x``, ...).
        base_rows_only: regress the six base equations alone (the measured contact wrenches
            against the bodies' motion: no joint torques and no joint terms), which determine
            the total mass and the first moments; needs force sensors.
        total_mass: the robot's known total mass, kg, held by a constraint row; None: none.
        flat_contacts: contact frames that pass a moment too (flat feet, a hand gripping):
            without force sensors six directions are projected out for each of them, three
            (a force) for the others, point feet.
        imu_frame: the frame fixed to the base that carries the log's IMU; None: the base.

    compute: `Compute` (chunking, device, processes, progress, the regressor's path).
    """

    # reading
    columns: Mapping[str, str] | None = option(
        None,
        group="reading",
        parse=parse.columns,
        help="map the library's column names to the log's: 't=time,q_j1=pos1' or a JSON "
        "object or file",
    )
    time_scale: float | None = option(
        None,
        group="reading",
        parse=parse.positive,
        metavar="S",
        help="seconds per unit of the time column, e.g. 1e-9 for ns (default: seconds, with "
        "ms, us and ns recognised from the sampling rate and stated in the report)",
    )
    drop_nan: bool = option(
        False, group="reading", help="drop rows holding NaN (default: report them and stop)"
    )
    drop_outliers: bool = option(
        False,
        group="reading",
        help="drop rows holding an isolated spike (one sample far from its neighbours and the "
        "signal's range; default: report them and stop)",
    )
    drop_cut_line: bool = option(
        False,
        group="reading",
        help="leave out a CSV log's last line when it has fewer or more fields than the header "
        "(a log cut while it was written; default: name that line and stop)",
    )
    max_seconds: float | None = option(
        None,
        group="reading",
        parse=parse.positive,
        metavar="S",
        help="use only the first S seconds of each log (a quick check)",
    )
    drive_gains: Sequence[float] | Mapping[str, float] | None = option(
        None,
        group="reading",
        parse=parse.drive_gains,
        metavar="G1,G2,...",
        help="drive gains, N m/A, that turn motor-current columns i_<joint> (A) into joint "
        "torques: one per joint in the robot's order, or joint=G,...",
    )
    topic: str | None = option(
        None,
        group="reading",
        help="the sensor_msgs/JointState topic of a ROS bag (default: the only one)",
    )
    effort: str = option(
        "torque",
        group="reading",
        choices=("torque", "current"),
        help="what a ROS bag's effort field holds: joint torques (N m) or motor currents (A, "
        "with --drive-gains)",
    )
    # preparation
    cutoff: float | str = option(
        "auto",
        group="preparation",
        parse=parse.auto_or("a positive cut-off in Hz", zero=False),
        help="low-pass cut-off, Hz, or 'auto': the one of 2..30 Hz that predicts held-out "
        "torques best inside the training part (torchjfa.data.choose_cutoff; "
        f"{DEFAULT_CUTOFF_HZ:g} Hz, with a warning, where the log is too short to choose)",
    )
    filter: str = option(
        "butterworth",
        group="preparation",
        choices=("butterworth", "savgol"),
        help="zero-phase low-pass filter: Butterworth (order 4) or Savitzky-Golay",
    )
    velocity: str = option(
        "auto",
        group="preparation",
        choices=("auto", "measured", "differentiate"),
        help="use the log's velocities ('measured'), differentiate the positions, or 'auto': "
        "the log's velocities if it has them",
    )
    period: float | str | None = option(
        "auto",
        group="preparation",
        parse=parse.auto_or("seconds", zero=False, none=True),
        help="excitation period in s, 'auto' (detect) or 'none'",
    )
    skip_start: float | str = option(
        0.0,
        group="preparation",
        parse=parse.auto_or("seconds", zero=True),
        help="seconds of start-up transient to drop, or 'auto', which needs a period",
    )
    decimate: int = option(1, group="preparation", help="keep every k-th sample after filtering")
    validation: float = option(
        0.2, group="preparation", help="held-out fraction at the end of each log"
    )
    trim_rest: bool = option(
        True,
        group="preparation",
        help="keep the standing still at the start and end of each log (default: drop it, "
        "keeping the filter's reach)",
    )
    # the model's joint terms
    friction: tuple[str, ...] | None = option(
        None,
        group="model",
        parse=joint_terms,
        help="joint terms, comma separated from viscous,coulomb,offset (friction) and armature "
        "(reflected motor inertia), or 'none' (default: viscous,coulomb,offset)",
    )
    coulomb_velocity: float | str = option(
        "auto",
        group="model",
        parse=parse.auto_or("a smoothing velocity >= 0 in rad/s", zero=True),
        metavar="V",
        help="smoothing velocity of the Coulomb friction term, rad/s: its column is "
        "tanh(qd / V), sign(qd) for 0; 'auto' chooses it with the cut-off by the same "
        "held-out prediction, from " + ", ".join(f"{v:g}" for v in COULOMB_GRID),
    )
    armature: str = option(
        "auto",
        group="model",
        choices=("auto", "off"),
        help="the motor's reflected inertia (armature) with the default joint terms: 'auto' "
        "adds it where it predicts held-out torques within the training part better by a "
        "standard error (geared arms), 'off' leaves it out; --friction ...,armature forces it",
    )
    fixed_joints: tuple[str, ...] = option(
        (),
        group="model",
        parse=parse.names,
        metavar="J1,J2",
        help="joints of the description to hold at q = 0 as fixed (a gripper's fingers, mimic "
        "joints), comma separated",
    )
    transmission: object = option(
        None,
        group="model",
        parse=str,
        metavar="FILE",
        help="the drive train, a JSON or YAML file {joints: [...], ratio: [[...]], motors: "
        "[...]} with motor velocity = ratio @ joint velocity: the joint terms then act per "
        "motor (coupled wrists too), and logs with motor columns q_<motor>, tau_<motor> or "
        "i_<motor> are converted to the joints",
    )
    # estimation
    estimator: str | LinearEstimator = option(
        "ols",
        group="estimator",
        choices=_estimators,
        help="the estimator (least squares by default; bayes-jfa is the paper's)",
    )
    estimator_options: Mapping[str, object] = option(
        group="estimator",
        default_factory=dict,
        parse=parse.estimator_options,
        metavar="K=V,...",
        help="options of the estimator, e.g. 'max_iter=500,ard=output' or a JSON object",
    )
    weighting: str = option(
        "residual",
        group="estimator",
        choices=("residual", "none"),
        help="weight each joint's equations by its inverse residual variance from a first "
        "least-squares fit (weighted least squares), or not at all",
    )
    input_noise: str | torch.Tensor | Sequence[float] = option(
        "auto",
        group="estimator",
        choices=("auto", "learn", "periods", "propagated"),
        help="the regressor's input noise (for the estimators that take it, and the "
        "projection's metric): the spread between excitation periods ('periods'), the log's "
        "sensor noise from its spectrum propagated through the preparation ('propagated'), "
        "learned ('learn'), or 'auto': periods when the training data hold two or more, else "
        "propagated for an estimator that takes an input noise (for a floating base, the "
        "base pose's and IMU's noise too)",
    )
    jackknife: int = option(
        20, group="estimator", help="blocks for the jackknife spread of the parameters, 0: none"
    )
    bias_correction: int | str = option(
        "auto",
        group="estimator",
        parse=parse.refits,
        metavar="N",
        help="refits on the log with re-drawn sensor noise for the noise's bias of the "
        "estimate (SIMEX), subtracted before the projection; 0: none; 'auto': "
        f"{AUTO_BIAS_REFITS} for ols, none for the other estimators",
    )
    # projection
    project: bool = option(
        True, group="projection", help="skip the projection onto consistent parameters"
    )
    parametrization: str = option(
        DEFAULT_PARAMETRIZATION,
        group="projection",
        choices=("log-cholesky", "virtual"),
        help="the projection's parameters: log-Cholesky, fully consistent (triangle "
        "inequalities too), or the paper's virtual parameters (mass > 0, inertia PSD)",
    )
    description_prior: float | str | None = option(
        "auto",
        group="projection",
        parse=parse.prior,
        help="pull the projection towards the description where the data are silent: 'auto' "
        "(the weight chosen by cross-validation over blocks of the training data) or a weight "
        "(prior std = a typical value of each kind / sqrt(weight)); 0 turns it off",
    )
    projection_options: Mapping[str, object] = option(
        group="projection", default_factory=dict, cli=False, help=""
    )
    # floating-base robots
    floating_base: bool | None = option(
        None,
        group="floating",
        action="switch",
        help="the robot's root link is a free-flying base (a legged robot, a humanoid) and the "
        "logs hold its pose (base_x, ..., base_qw), contacts (contact_<frame>) and, where "
        "measured, contact forces (f_<frame>_x, ...); by default where the first log has "
        "base-pose columns",
    )
    base_rows_only: bool = option(
        False,
        group="floating",
        help="regress the six base equations alone: the measured contact wrenches against the "
        "bodies' motion, without joint torques or joint terms (needs force sensors); they "
        "determine the total mass and the centre of mass",
    )
    total_mass: float | None = option(
        None,
        group="floating",
        parse=parse.positive,
        metavar="KG",
        help="the robot's known total mass, held by a constraint on the sum of the masses",
    )
    flat_contacts: tuple[str, ...] = option(
        (),
        group="floating",
        parse=parse.names,
        metavar="F1,F2",
        help="contact frames that pass a moment too (flat feet, a hand gripping): with "
        "contact flags only, six directions are projected out for each, three (a force) for "
        "the others (point feet)",
    )
    imu_frame: str | None = option(
        None,
        group="floating",
        metavar="FRAME",
        help="the frame of the description that carries the log's IMU (imu_wx.., imu_ax..), "
        "fixed to the base; by default the base frame itself",
    )
    compute: Compute = option(group="compute", default_factory=Compute, cli=False, help="")

    def __post_init__(self) -> None:
        if self.friction is not None:
            object.__setattr__(self, "friction", joint_terms(self.friction))
        for f in fields(self):
            choices = f.metadata.get("choices")
            value = getattr(self, f.name)
            if choices is not None and isinstance(value, str):
                choice(f.name, value, choices() if callable(choices) else choices)
        check_numbers(self)
        check_reading(self)
        if self.transmission is not None:
            try:
                object.__setattr__(self, "transmission", read_transmission(self.transmission))
            except (OSError, ValueError) as exc:
                raise IdentificationError(f"transmission: {exc}") from None
        check_estimator_options(self)
        w = self.description_prior
        if w not in (None, "auto") and (
            isinstance(w, bool | str) or not 0 <= parse.number(w) < float("inf")
        ):
            raise IdentificationError(
                f"description_prior must be None, a weight >= 0 or 'auto', got {w!r}"
            )
        if self.description_prior not in (None, "auto") and not self.project:
            raise IdentificationError(
                "the description prior acts in the projection: it needs project=True"
            )
        if self.total_mass is not None and not 0 < parse.number(self.total_mass) < float("inf"):
            raise IdentificationError(
                f"total_mass must be None or a positive mass in kg, got {self.total_mass!r}"
            )
        object.__setattr__(self, "flat_contacts", frame_names(self.flat_contacts, "flat_contacts"))
        if self.skip_start == "auto" and self.period is None:
            raise IdentificationError("skip_start='auto' needs a period ('auto' or seconds)")
        if (
            self.friction is not None
            and "coulomb" not in self.friction
            and self.coulomb_velocity != "auto"
        ):
            raise IdentificationError(
                "coulomb_velocity smooths the Coulomb term, which friction does not include"
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


def cli_fields(cls=Options) -> list[Field]:
    """The fields of ``cls`` (and of its `Compute`) the command line sets, in `GROUPS` order."""
    out = [f for f in fields(cls) if f.metadata.get("cli", False)]
    if cls is Options:
        out += cli_fields(Compute)
    order = list(GROUPS)
    return sorted(out, key=lambda f: order.index(f.metadata["group"]))
