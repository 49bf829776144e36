"""The seed paper's robot experiments (section IV.B/C, Tables I and II), in simulation.

For the simulated 7-DoF head (420 Hz) and 10-DoF arm (480 Hz) of `torchjfa.sim`, `run_robot`:

1. records a noisy identification log of the robot tracking a random sum-of-sinusoids
   excitation with its unmodeled effects (armature, dry friction, cable stiffness) ON;
2. forms the regression's `Moments` in contiguous time blocks (the folds of LASSO's
   cross-validation) and estimates the regressor's input noise from the repeated periods
   (`torchjfa.data.regressor_noise`);
3. identifies the parameters with each method and projects them onto physically consistent
   parameters (`torchjfa.physical.project`, virtual parametrisation, eq. 5 and 8):

   - ``"ridge"``: ridge regression (alpha by GCV instead of the paper's hand tuning), then
     gradient descent (LBFGS) on the virtual parameters, metric ``X^T X``;
   - ``"lasso"``: LASSO (alpha by 5-fold contiguous CV) + projection, metric ``X^T X``;
   - ``"stepwise"``: forward stepwise (F-test, p < 0.05) + projection, metric ``X^T X``;
   - ``"bjfa"``: the seed's Bayesian JFA as written (`BayesianJFA()`) + projection with its own
     input-noise estimate, metric ``X^T X + N diag(noise_x_)`` (eq. 8);
   - ``"bjfa-noise"``: Bayesian JFA with the input noise measured from the repeated periods held
     fixed, and the projection's metric ``X^T X + N diag(input_noise)``;

4. evaluates each projected estimate, and the true parameters as a reference, with
   computed-torque control in MuJoCo on a held-out test trajectory (unmodeled effects ON), and
   scores held-out torque prediction (nMSE) on a log of the same test trajectory.

`format_table` prints a result in the paper's layout, `plot_tracking` draws the per-joint
tracking errors, `goal_check` tests the issue's goal (all three, with `RobotResult`, live in
`experiments._results` and are re-exported here). ``scripts/reproduce_tables.py`` and
``notebooks/robot_identification.ipynb`` are thin shells over `run`. Nothing is tuned on the
test trajectory: every hyper-parameter is fixed or chosen on the training log.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping, Sequence

import torch

from torchjfa._util import progress_bar
from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import (
    Options,
    fit,
    make_consistent,
    residual_joint_weights,
    stream_moments,
)
from torchjfa.metrics import nmse
from torchjfa.physical import check
from torchjfa.sim import (
    DEFAULT_RATES,
    ControlResult,
    SensorNoise,
    evaluate_control,
    generate_log,
    load_robot,
    model_path,
    random_trajectory,
    regressor_noise,
    true_parameters,
)
from torchjfa.stats import Moments

from ._results import (
    LABELS,
    METHODS,
    REFERENCE,
    Identified,
    RobotResult,
    format_table,
    goal_check,
    plot_tracking,
)

__all__ = [
    "METHODS",
    "LABELS",
    "REFERENCE",
    "Identified",
    "RobotResult",
    "true_theta",
    "block_moments",
    "fit_methods",
    "evaluate_control",
    "run_robot",
    "run",
    "format_table",
    "goal_check",
    "plot_tracking",
]

_SIGNALS = {
    "measured": ("q", "qd", "qdd", "tau"),
    "true": ("q_true", "qd_true", "qdd_true", "tau_true"),
}


def true_theta(model: RigidBodyModel, robot: str) -> torch.Tensor:
    """The simulated robot's true parameters: the MJCF inertials, its viscous damping as fv and,
    where the model has the term, its armature as ia (`torchjfa.sim.true_parameters`); dry
    friction and cable stiffness stay unmodeled."""
    return true_parameters(robot, model, armature=True)


def block_moments(
    model: RigidBodyModel,
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    tau: torch.Tensor,
    *,
    n_blocks: int = 5,
    chunk_size: int = 4096,
    progress: bool = False,
) -> list[Moments]:
    """`Moments` of ``n_blocks`` contiguous time blocks of a log (fold moments for CV):
    `torchjfa.identification.stream_moments` with ``n_folds=n_blocks``.

    Args:
        model: the robot model (its regressor).
        q, qd, qdd, tau: ``(n, n_dof)`` signals in the model's joint order (rad, rad/s, rad/s^2,
            N m).
        n_blocks: number of blocks, at least 2 and at most n.
        chunk_size: samples per regressor call.
        progress: show a progress bar.

    Returns:
        A list of ``n_blocks`` `Moments` whose sum is the whole log's.
    """
    n = q.shape[0]
    if isinstance(n_blocks, bool) or not isinstance(n_blocks, int) or not 2 <= n_blocks <= n:
        raise ValueError(f"n_blocks must be an int in [2, {n}], got {n_blocks!r}")
    log = {"q": q, "qd": qd, "qdd": qdd, "tau": tau}
    return stream_moments(model, log, n_folds=n_blocks, chunk_size=chunk_size, progress=progress)


#: each method's estimator (`torchjfa.estimators.make`) and its default options
_ESTIMATORS = {
    "ridge": ("ridge", {}),
    "lasso": ("lasso", {"n_alphas": 20, "tol": 1e-6, "max_iter": 2000}),
    "stepwise": ("stepwise", {}),
    "bjfa": ("bayes-jfa", {"max_iter": 20000}),
    "bjfa-noise": ("bayes-jfa", {"max_iter": 20000}),
}


def _options(method: str, input_noise, options: Mapping) -> Options:
    """The `torchjfa.identification.Options` of one method on moments already formed: its
    estimator and options, the virtual parametrisation, no prior, no jackknife."""
    if method not in _ESTIMATORS:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    name, defaults = _ESTIMATORS[method]
    noise = "learn"
    if method == "bjfa-noise":
        if input_noise is None:
            raise ValueError("method 'bjfa-noise' needs input_noise (e.g. from regressor_noise)")
        noise = input_noise
    return Options(
        estimator=name,
        estimator_options={**defaults, **options.get(method.split("-")[0], {})},
        weighting="none",
        input_noise=noise,
        jackknife=0,
        bias_correction=0,
        parametrization="virtual",
        description_prior=None,
        projection_options=dict(options.get("project") or {}),
    )


def fit_methods(
    model: RigidBodyModel,
    folds: Sequence[Moments],
    *,
    methods: Sequence[str] = METHODS,
    input_noise=None,
    options: Mapping | None = None,
    progress: bool = False,
) -> dict[str, Identified]:
    """Fit every method on the fold moments and project each estimate (see the module):
    `torchjfa.identification.fit` and `torchjfa.identification.make_consistent` per method.

    Args:
        model: the robot model (the parameter layout).
        folds: `Moments` of contiguous blocks of the training log (from `block_moments`).
        methods: keys of `METHODS`.
        input_noise: ``(n_params,)`` per-column input-noise variance (``PeriodNoise.input_noise``),
            needed by ``"bjfa-noise"``.
        options: extra keywords per step: ``"bjfa"`` (`BayesianJFA`, default
            ``max_iter=20000``), ``"lasso"`` (`Lasso`, default ``n_alphas=20, tol=1e-6,
            max_iter=2000``), ``"stepwise"`` (`Stepwise`), ``"project"`` (`project`).
        progress: show a progress bar over the methods.

    Returns:
        method -> `Identified`, in the order of ``methods``.
    """
    options = dict(options or {})
    folds = list(folds)
    if len(folds) < 2 or not all(isinstance(f, Moments) for f in folds):
        raise TypeError("folds must be a list of at least two torchjfa.Moments")
    out = {}
    with progress_bar(total=len(methods), desc="identify", enabled=progress) as bar:
        for method in methods:
            opts = _options(method, input_noise, options)
            start = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                # non-convergence is reported, not raised
                result = fit(model, folds, options=opts)
            est = result.estimator
            fit_s = time.perf_counter() - start
            start = time.perf_counter()
            proj = make_consistent(result, opts).projection
            out[method] = Identified(
                method=method,
                theta_hat=est.coef_.detach().clone(),
                theta=proj.theta.detach().clone(),
                estimator=est,
                fit_s=fit_s,
                project_s=time.perf_counter() - start,
                consistent_before=check(est.coef_, model).ok,
                consistent_after=check(proj.theta, model).weakly_ok,
                projection_cost=proj.cost,
                projection_converged=proj.converged,
                warnings=tuple(dict.fromkeys(str(w.message) for w in caught)),
            )
            bar.update(1)
    return out


def _nmse(Y: torch.Tensor, tau: torch.Tensor, theta: torch.Tensor) -> float:
    """Mean over joints of MSE_j / var(tau_j); ``Y (n, n_dof, p)``, ``tau (n, n_dof)``."""
    return float(nmse(Y @ theta, tau))


def run_robot(
    robot: str,
    *,
    n_samples: int = 500_000,
    methods: Sequence[str] = METHODS,
    noise: SensorNoise | None = None,
    unmodeled: bool | Mapping = True,
    signals: str = "measured",
    base_frequency: float = 0.25,
    test_duration: float = 4.0,
    control: bool = True,
    noise_periods: int | None = 10,
    n_blocks: int = 5,
    seed: int = 0,
    options: Mapping | None = None,
    weighting: str = "none",
    friction: Sequence[str] = ("viscous",),
    progress: bool = False,
) -> RobotResult:
    """The whole experiment for one robot (see the module docstring).

    Args:
        robot: ``"head"`` or ``"arm"``.
        n_samples: training samples at the control rate (the paper: about 500,000).
        methods: keys of `METHODS`.
        noise: sensor noise of the training and test logs (default `SensorNoise()`).
        unmodeled: the robot's joint effects, for the logs and the control runs.
        signals: identify from the ``"measured"`` (noisy, differentiated) signals or from the
            simulator's ``"true"`` ones (exactness checks).
        base_frequency: Hz, f0 of the training excitation (its period must be whole samples).
        test_duration: s, length of the held-out control run and torque log.
        control: run the computed-torque evaluation (False: torque nMSE only).
        noise_periods: periods used by `regressor_noise` (None: all).
        n_blocks: contiguous blocks of the training log (LASSO's CV folds).
        seed: seeds the training excitation and noise; the test trajectory uses ``seed + 1000``.
        options: passed to `identify`.
        weighting: ``"none"`` (every equation weight 1, the paper's setting) or
            ``"residual"``: each joint's equations weighted by its inverse residual variance
            after a first OLS fit (`torchjfa.identification.residual_joint_weights`); the input noise
            is then that of the weighted rows.
        friction: the identification model's joint terms (the paper's: viscous only);
            ``("viscous", "armature")`` models the simulated robots' armature, which the
            reference row then holds at its true value.
        progress: show progress bars.

    Returns:
        A `RobotResult`.
    """
    if signals not in _SIGNALS:
        raise ValueError(f"signals must be one of {tuple(_SIGNALS)}, got {signals!r}")
    if weighting not in ("none", "residual"):
        raise ValueError(f"weighting must be 'none' or 'residual', got {weighting!r}")
    noise = SensorNoise() if noise is None else noise
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = now - clock
        clock = now

    mj = load_robot(robot, unmodeled=unmodeled)
    train_traj = random_trajectory(mj, base_frequency=base_frequency, seed=seed)
    test_traj = random_trajectory(mj, seed=seed + 1000)
    kw = {"unmodeled": unmodeled, "noise": noise, "progress": progress}
    log = generate_log(robot, n_samples=n_samples, trajectory=train_traj, seed=seed, **kw)
    n_test = int(round(test_duration * DEFAULT_RATES[robot]))
    test = generate_log(robot, n_samples=n_test, trajectory=test_traj, seed=seed + 1000, **kw)
    lap("simulate")
    model = RigidBodyModel.from_mjcf(model_path(robot), friction=tuple(friction))
    log, test = log.reorder(model.joint_names), test.reorder(model.joint_names)
    sig = [getattr(log, k) for k in _SIGNALS[signals]]
    folds, weights = _training_moments(model, sig, weighting, n_blocks, progress)
    lap("moments")
    period_noise = regressor_noise(
        model, log, max_periods=noise_periods, progress=progress, joint_weights=weights
    )
    lap("noise")
    found = fit_methods(
        model,
        folds,
        methods=methods,
        input_noise=period_noise.input_noise,
        options=options,
        progress=progress,
    )
    lap("identify")
    thetas = {m: found[m].theta for m in methods}
    thetas[REFERENCE] = true_theta(model, robot)
    clean = [getattr(test, k) for k in _SIGNALS["true"]]
    meas = [getattr(test, k) for k in _SIGNALS["measured"]]
    Y_clean, Y_meas = model.regressor(*clean[:3]), model.regressor(*meas[:3])
    lap("nmse")
    ctrl = {}
    if control:
        ctrl = evaluate_control(
            robot, model, thetas, test_traj, duration=test_duration, unmodeled=unmodeled,
            progress=progress,
        )  # fmt: skip
    lap("control")
    rows = [
        _row(
            robot,
            name,
            theta,
            model,
            ctrl.get(name),
            found.get(name),
            nmse_clean=_nmse(Y_clean, clean[3], theta),
            nmse_measured=_nmse(Y_meas, meas[3], theta),
        )
        for name, theta in thetas.items()
    ]
    settings = {
        "robot": robot, "n_samples": n_samples, "control_rate": DEFAULT_RATES[robot],
        "n_params": model.n_params, "signals": signals, "unmodeled": unmodeled is not False,
        "noise": [noise.position_std, noise.velocity_std, noise.torque_std],
        "base_frequency": base_frequency, "test_duration": test_duration, "seed": seed,
        "noise_periods": period_noise.n_periods, "n_blocks": n_blocks, "weighting": weighting,
        "joint_weights": None if weights is None else weights.tolist(),
        "friction": list(model.friction),
    }  # fmt: skip
    return RobotResult(robot, rows, found, ctrl, period_noise, settings, timings)


def _training_moments(
    model: RigidBodyModel, sig: Sequence, weighting: str, n_blocks: int, progress: bool
) -> tuple[list[Moments], torch.Tensor | None]:
    """``(folds, joint_weights)``: the ``n_blocks`` contiguous block `Moments` of the training
    signals ``sig`` (q, qd, qdd, tau), each joint's rows weighted by its inverse residual
    variance (`residual_joint_weights`) when ``weighting`` is ``"residual"`` (else weights None).
    """
    if weighting != "residual":
        return block_moments(model, *sig, n_blocks=n_blocks, progress=progress), None
    arrays = dict(zip(("q", "qd", "qdd", "tau"), sig, strict=True))
    weights = residual_joint_weights(model, arrays, progress=progress)
    folds = stream_moments(
        model, arrays, n_folds=n_blocks, joint_weights=weights, progress=progress
    )
    return folds, weights


def _row(
    robot: str,
    name: str,
    theta: torch.Tensor,
    model: RigidBodyModel,
    res: ControlResult | None,
    ident: Identified | None,
    *,
    nmse_clean: float,
    nmse_measured: float,
) -> dict:
    """One row of `RobotResult.rows`: the control run ``res`` (None without one) and the
    identification ``ident`` (None for the reference) of method ``name``; NaN where the run
    failed or there is no such number."""
    ok = res is not None and res.success
    nan = float("nan")
    return {
        "robot": robot,
        "method": name,
        "label": LABELS[name],
        "success": ok if res is not None else None,
        "reason": None if res is None else res.reason,
        "rms_position": res.mean_rms_position if ok else nan,
        "rms_velocity": res.mean_rms_velocity if ok else nan,
        "rms_feedback": res.mean_rms_feedback if ok else nan,
        "nmse_clean": nmse_clean,
        "nmse_measured": nmse_measured,
        "fit_s": ident.fit_s if ident else nan,
        "project_s": ident.project_s if ident else nan,
        "consistent_before": ident.consistent_before if ident else check(theta, model).ok,
        "consistent_after": ident.consistent_after if ident else check(theta, model).ok,
        "projection_cost": ident.projection_cost if ident else nan,
    }


#: default training samples per robot of the full run (the paper: about 500,000; see docs)
FULL_SAMPLES = 500_000
#: the smoke configuration: a 1 s excitation period, 4 periods, short control runs
SMOKE = {
    "n_samples_periods": 3,
    "base_frequency": 1.0,
    "test_duration": 0.25,
    "options": {
        "bjfa": {"max_iter": 200},
        "lasso": {"n_alphas": 2, "tol": 1e-4, "max_iter": 10},
        "stepwise": {"max_features": 10},
        "project": {"max_iter": 10, "warm_start": False},
    },
}


def run(
    robots: Sequence[str] = ("head", "arm"),
    *,
    smoke: bool = False,
    n_samples: int | None = None,
    test_duration: float | None = None,
    seed: int = 0,
    progress: bool = False,
    **kwargs,
) -> dict[str, RobotResult]:
    """Run `run_robot` for each robot, full size or in smoke mode.

    Args:
        robots: robot names.
        smoke: tiny sizes (`SMOKE`: 3 one-second periods of training data, 0.25 s of control,
            few iterations) so both robots run end to end in well under a minute.
        n_samples: training samples (default `FULL_SAMPLES`; smoke: 3 periods).
        test_duration: s (default 4.0; smoke 0.25).
        seed: see `run_robot`.
        progress: show progress bars.
        **kwargs: passed to `run_robot`.

    Returns:
        robot -> `RobotResult`.
    """
    out = {}
    for robot in robots:
        kw = dict(kwargs)
        if smoke:
            kw.setdefault("base_frequency", SMOKE["base_frequency"])
            kw.setdefault("options", SMOKE["options"])
            kw.setdefault("noise_periods", None)
            default_n = int(SMOKE["n_samples_periods"] * DEFAULT_RATES[robot])
            default_t = SMOKE["test_duration"]
        else:
            default_n, default_t = FULL_SAMPLES, 4.0
        out[robot] = run_robot(
            robot,
            n_samples=default_n if n_samples is None else n_samples,
            test_duration=default_t if test_duration is None else test_duration,
            seed=seed,
            progress=progress,
            **kw,
        )
    return out
