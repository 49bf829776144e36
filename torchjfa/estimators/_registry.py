"""Estimators by name: `make`, `register`, `available`.

The command line (``torchjfa identify --estimator NAME``), the experiments and a user's script
name estimators by the same strings; `make` turns a name and keyword options into an
estimator. A third party plugs its own estimator in with `register`, after which every flow
that takes a name accepts it. The estimator must follow the `LinearEstimator` protocol
(``fit_moments``, ``coef_``, ``needs_folds`` and ``cv``); subclassing `LinearEstimator` is the
simplest way.

Example::

    from torchjfa import estimators

    lasso = estimators.make("lasso", alpha=0.1, fit_intercept=False)
    estimators.register("my-ols", MyOLS)  # a LinearEstimator subclass
    mine = estimators.make("my-ols", fit_intercept=False)
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

from ._base import LinearEstimator
from ._jfa import JFA, BayesianJFA
from ._lasso import Lasso
from ._linear import OLS, TLS, Ridge
from ._pls import PLS
from ._stepwise import Stepwise

__all__ = ["available", "make", "register", "takes"]

# name -> factory (a class or function taking keyword options). The library's own estimators;
# `register` adds to it for the life of the process.
_FACTORIES: dict[str, Callable[..., LinearEstimator]] = {
    "bayes-jfa": BayesianJFA,
    "jfa": JFA,
    "ols": OLS,
    "ridge": Ridge,
    "tls": TLS,
    "pls": PLS,
    "lasso": Lasso,
    "stepwise": Stepwise,
}


def available() -> tuple[str, ...]:
    """The names `make` accepts: the library's estimators in the order of the command line's
    ``--estimator`` choices, then the registered ones in the order they were registered."""
    return tuple(_FACTORIES)


def register(name: str, factory: Callable[..., LinearEstimator], *, replace: bool = False):
    """Make ``factory`` available to `make` (and every flow that takes an estimator's name).

    Args:
        name: a non-empty string without whitespace, e.g. ``"my-ridge"``.
        factory: a callable taking keyword options and returning a `LinearEstimator` (usually
            the estimator's class). An estimator that chooses a hyper-parameter by
            cross-validation overrides `LinearEstimator.needs_folds` and reads ``cv``.
        replace: allow ``name`` to be registered already (replacing its factory); by default
            registering a taken name is an error, so that a plug-in cannot silently shadow
            another estimator.

    Returns:
        ``factory``.

    Raises:
        TypeError: if ``factory`` is not callable or ``name`` not a string.
        ValueError: on an empty name, whitespace in it, or a taken name without ``replace``.
    """
    if not isinstance(name, str):
        raise TypeError(f"an estimator's name must be a string, got {type(name).__name__}")
    if not name or any(c.isspace() for c in name):
        raise ValueError(f"an estimator's name must be non-empty without whitespace: {name!r}")
    if not callable(factory):
        raise TypeError(f"factory must be callable (e.g. a class), got {type(factory).__name__}")
    if name in _FACTORIES and not replace:
        raise ValueError(
            f"an estimator named {name!r} is already registered ({_FACTORIES[name]!r}); "
            "pass replace=True to replace it"
        )
    _FACTORIES[name] = factory
    return factory


def _options(factory) -> tuple[list[str], bool]:
    """The factory's keyword options and whether it takes any (``**kwargs``)."""
    try:
        params = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):  # no signature to read (some builtins): let it check
        return [], True
    kinds = (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    names = [p.name for p in params if p.kind in kinds]
    return names, any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params)


def takes(name: str, option: str) -> bool:
    """Whether the estimator registered as ``name`` takes the keyword option ``option`` (e.g.
    ``"input_noise"``, which the identification flow gives where an estimator takes it)."""
    if name not in _FACTORIES:
        raise ValueError(f"unknown estimator {name!r}; available: {', '.join(_FACTORIES)}")
    accepted, any_keyword = _options(_FACTORIES[name])
    return option in accepted or any_keyword


def make(name: str, **options) -> LinearEstimator:
    """A new estimator by name, with keyword options (its constructor's arguments).

    Args:
        name: one of `available`: ``"bayes-jfa"`` (`BayesianJFA`), ``"jfa"`` (`JFA`),
            ``"ols"``, ``"ridge"``, ``"tls"``, ``"pls"``, ``"lasso"``, ``"stepwise"`` or a
            registered name.
        **options: passed to the factory, e.g. ``fit_intercept=False`` (robot identification
            has no intercept: the command line passes it), ``max_iter=2000``.

    Returns:
        The estimator, unfitted.

    Raises:
        ValueError: on an unknown name, or an option the factory does not take (the message
            lists the names, or the options, it accepts).
        TypeError: if the factory returns something other than a `LinearEstimator`.
    """
    if name not in _FACTORIES:
        raise ValueError(f"unknown estimator {name!r}; available: {', '.join(_FACTORIES)}")
    factory = _FACTORIES[name]
    accepted, any_keyword = _options(factory)
    unknown = sorted(set(options) - set(accepted))
    if unknown and not any_keyword:
        raise ValueError(
            f"estimator {name!r} has no option {', '.join(map(repr, unknown))}; its options: "
            f"{', '.join(accepted) or 'none'}"
        )
    estimator = factory(**options)
    if not isinstance(estimator, LinearEstimator):
        raise TypeError(
            f"the factory of {name!r} returned a {type(estimator).__name__}, not a "
            "torchjfa.estimators.LinearEstimator"
        )
    return estimator
