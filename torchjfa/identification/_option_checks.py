"""The checks `Options` runs on its values (each function takes the `Options`): ranges, the
reading options, the estimator's options; each raises `IdentificationError` with what was
expected."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from . import _parse as parse
from ._errors import IdentificationError

__all__ = ["check_estimator_options", "check_numbers", "check_reading", "choice"]


def check_numbers(o) -> None:
    """The numeric options' ranges."""
    if o.cutoff != "auto" and not 0 < parse.number(o.cutoff) < float("inf"):
        raise IdentificationError(f"cutoff must be 'auto' or a positive Hz, got {o.cutoff!r}")
    v_c = o.coulomb_velocity
    if v_c != "auto" and not 0 <= parse.number(v_c) < float("inf"):
        raise IdentificationError(
            f"coulomb_velocity must be 'auto' or a number >= 0, rad/s, got {v_c!r}"
        )
    if not 0.0 < parse.number(o.validation) < 1.0:
        raise IdentificationError(f"validation must be a fraction in (0, 1), got {o.validation}")
    if isinstance(o.decimate, bool) or not isinstance(o.decimate, int) or o.decimate < 1:
        raise IdentificationError(f"decimate must be a whole number >= 1, got {o.decimate!r}")
    k = o.jackknife
    if isinstance(k, bool) or not isinstance(k, int) or k == 1 or k < 0:
        raise IdentificationError(f"jackknife must be 0 (off) or at least 2 blocks, got {k!r}")
    n = o.bias_correction
    if n != "auto" and (isinstance(n, bool) or not isinstance(n, int) or n == 1 or n < 0):
        raise IdentificationError(
            f"bias_correction must be 'auto', 0 (off) or at least 2 refits, got {n!r}"
        )


def check_reading(o) -> None:
    """The reading options: a positive time scale, positive drive gains, joint names."""
    if o.time_scale is not None and not 0 < parse.number(o.time_scale) < float("inf"):
        raise IdentificationError(f"time_scale must be None or positive, got {o.time_scale!r}")
    gains = o.drive_gains
    if gains is not None:
        values = list(gains.values()) if isinstance(gains, Mapping) else gains
        if isinstance(values, str) or not all(0 < parse.number(g) < float("inf") for g in values):
            raise IdentificationError(
                f"drive_gains must be positive N m/A per joint (a sequence in the robot's joint "
                f"order or {{joint: gain}}), got {gains!r}"
            )
    fixed = o.fixed_joints
    if isinstance(fixed, str):
        object.__setattr__(o, "fixed_joints", (fixed,))
    elif not all(isinstance(j, str) for j in fixed):
        raise IdentificationError(f"fixed_joints must be joint names, got {fixed!r}")
    else:
        object.__setattr__(o, "fixed_joints", tuple(fixed))


def check_estimator_options(o) -> None:
    """``estimator_options`` only with an estimator given by name, and only options it takes."""
    if not o.estimator_options:
        return
    if not isinstance(o.estimator, str):
        raise IdentificationError(
            f"estimator_options {dict(o.estimator_options)} apply to an estimator given by "
            f"name; the {type(o.estimator).__name__} given is used as it is (set its options "
            "when you make it)"
        )
    from ..estimators import takes

    bad = sorted(k for k in o.estimator_options if not takes(o.estimator, k))
    if bad:
        raise IdentificationError(
            f"estimator {o.estimator!r} takes no option {', '.join(bad)} (see "
            f"torchjfa.estimators.make({o.estimator!r}) for its options)"
        )


def choice(name: str, value, allowed: Sequence[str]) -> None:
    if value not in allowed:
        raise IdentificationError(f"{name} must be one of {tuple(allowed)}, got {value!r}")


def frame_names(value, what: str) -> tuple[str, ...]:
    """``value`` (a name or several) as a tuple of frame names, or an error naming ``what``."""
    names = (value,) if isinstance(value, str) else tuple(value)
    if not all(isinstance(n, str) for n in names):
        raise IdentificationError(f"{what} must be frame names, got {value!r}")
    return names
