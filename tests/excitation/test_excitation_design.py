"""Optimised excitations hold their limits on a 10x finer grid; broken limits raise; gradients."""

import math
import sysconfig
from pathlib import Path

import numpy as np
import pytest
import torch

import torchjfa
from torchjfa.dynamics import RigidBodyModel
from torchjfa.excitation import (
    WorkspaceBox,
    _design,
    base_directions,
    check_limits,
    constrain_coefficients,
    constraint_violations,
    criterion_value,
    fourier_states,
    information_matrix,
    limits_from_model,
    optimize_excitation,
    random_excitation,
    soft_condition,
    trajectory_information,
)
from torchjfa.excitation._information import period_grid
from torchjfa.sim import model_path

ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
XARM7 = ERD / "xarm_description/urdf/xarm7.urdf"
SMALL = {"duration": 4.0, "base_frequency": 0.25, "harmonics": 3, "n_grid": 60, "n_starts": 1,
         "max_iter": 8, "polish_iter": 8}  # fmt: skip
RATE = 50.0


def _model(name):
    if name in ("head", "arm"):
        return RigidBodyModel.from_mjcf(model_path(name))
    if name == "panda":
        return RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    if not XARM7.is_file():
        pytest.skip("example-robot-data is not installed")
    return RigidBodyModel.from_urdf(XARM7)


def _independent_check(model, traj, limits, raw):
    """The limits, from the description's numbers and the margin, on a grid 10x the rate.

    Evaluated through the trajectory's sinusoid form (numpy, another code path) and
    `RigidBodyModel.inverse_dynamics`, not through the code that optimised it.
    """
    t = np.arange(int(traj.period * RATE * 10) + 1) / (RATE * 10)
    q, qd, qdd = traj.to_sinusoid().evaluate_numpy(t)
    lo, hi, vel, acc, eff = raw
    margin = 0.05 * (hi - lo)
    # 1e-9: rounding of sums of a few sinusoids of size ~1
    assert np.all(q >= lo + margin - 1e-9) and np.all(q <= hi - margin + 1e-9)
    assert np.all(np.abs(qd) <= vel + 1e-9)
    assert np.all(np.abs(qdd) <= acc + 1e-9)
    tau = model.inverse_dynamics(q, qd, qdd, model.nominal_theta).numpy()
    assert np.all(np.abs(tau) <= eff * (1 + 1e-9))


@pytest.mark.parametrize("name", ["head", "arm", "panda", "xarm7"])
def test_limits_hold_on_a_ten_times_finer_grid(name):
    model = _model(name)
    n = model.n_dof
    if name in ("head", "arm"):  # MJCF ranges only: give velocity and acceleration limits
        user = {"velocity": 1.0, "acceleration": 2.0}
        raw_v, raw_a, raw_t = np.full(n, 1.0), np.full(n, 2.0), np.full(n, np.inf)
    else:  # URDF <limit velocity effort>, plus an acceleration limit
        user = {"acceleration": 3.0}
        joints = {j.name: j for j in model.chain.get_joints()}
        raw_v = np.array([joints[j].velocity_limits[1] for j in model.joint_names])
        raw_t = np.array([joints[j].effort_limits[1] for j in model.joint_names])
        raw_a = np.full(n, 3.0)
    joints = {j.name: j for j in model.chain.get_joints()}
    lo = np.array([joints[j].limits[0] for j in model.joint_names], dtype=float)
    hi = np.array([joints[j].limits[1] for j in model.joint_names], dtype=float)
    limits = limits_from_model(model, **user)
    res = optimize_excitation(model, limits, rate=RATE, seed=1, **SMALL)
    _independent_check(model, res.trajectory, limits, (lo, hi, raw_v, raw_a, raw_t))
    assert min(res.margins.values()) >= 0.0
    assert set(res.margins) >= {"position", "velocity", "acceleration"}
    # the optimised motion carries information about every identifiable direction
    assert np.isfinite(res.condition_number)


def test_workspace_box_holds():
    model = _model("panda")
    # the hand's origin stays above a table 0.25 m above the base
    box = WorkspaceBox("panda_hand", (-2.0, -2.0, 0.25), (2.0, 2.0, 2.0))
    posture = [0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8]
    limits = limits_from_model(model, workspace=[box])
    res = optimize_excitation(model, limits, rate=RATE, seed=0, posture=posture, **SMALL)
    t = np.arange(int(res.trajectory.period * RATE * 10) + 1) / (RATE * 10)
    q = res.trajectory.to_sinusoid().evaluate_numpy(t)[0]
    # independent forward kinematics: the package's float32 chain, to float32 accuracy
    fk = model.chain.forward_kinematics(torch.as_tensor(q, dtype=torch.float32))
    z = fk["panda_hand"].get_matrix()[:, 2, 3].double().numpy()
    assert z.min() >= 0.25 - 1e-5
    assert "workspace" in res.margins


def test_broken_limit_raises_with_the_joint_and_the_kind():
    model = _model("head")
    limits = limits_from_model(model)
    res = optimize_excitation(model, limits, rate=RATE, seed=0, **SMALL)
    peak = np.abs(res.trajectory.evaluate_numpy(np.linspace(0, 4, 2001))[1]).max(0)
    j = int(np.argmax(peak))
    tight = limits_from_model(model, velocity={model.joint_names[j]: 0.5 * peak[j]})
    with pytest.raises(ValueError, match=rf"{model.joint_names[j]}: \|velocity\|"):
        check_limits(model, res.trajectory, tight, rate=RATE)
    # a torque limit below the gravity torque at the posture cannot be met by any motion
    panda = _model("panda")
    with pytest.raises(ValueError, match=r"panda_joint2: \|torque\|"):
        optimize_excitation(panda, limits_from_model(panda, torque=1e-3), rate=RATE, **SMALL)
    with pytest.raises(ValueError, match="posture is outside"):
        optimize_excitation(model, limits, posture=[5.0] * 7, **SMALL)
    with pytest.raises(ValueError, match="whole number of periods"):
        optimize_excitation(model, limits, **{**SMALL, "duration": 3.0})


@pytest.mark.parametrize("kind", ["d", "condition", "e", "soft 2", "soft 32"])
def test_criterion_gradient_matches_finite_differences(kind):
    model = RigidBodyModel.from_mjcf(model_path("head"))
    limits = limits_from_model(model)
    basis = base_directions(model, limits, generator=torch.Generator().manual_seed(0))
    t = torch.arange(24, dtype=torch.float64) * (4.0 / 24)
    q0 = torch.zeros(7, dtype=torch.float64)
    g = torch.Generator().manual_seed(1)
    a = (0.3 * torch.randn(7, 3, generator=g, dtype=torch.float64)).requires_grad_(True)
    b = (0.3 * torch.randn(7, 3, generator=g, dtype=torch.float64)).requires_grad_(True)

    def f(a, b):
        a, b = constrain_coefficients(a, b)
        M = information_matrix(model, *fourier_states(t, q0, a, b, 0.25), basis)
        if kind.startswith("soft"):
            return soft_condition(M, float(kind.split()[1]))
        return criterion_value(M, kind)

    assert torch.autograd.gradcheck(f, (a, b), eps=1e-6, atol=1e-6, rtol=1e-5)


def test_soft_condition_written_out_and_bounds_the_condition_number():
    M = torch.diag(torch.tensor([4.0, 1.0, 0.25], dtype=torch.float64))
    for p in (1.0, 2.0, 8.0):
        ratio = (4**p + 1 + 0.25**p) ** (1 / p) * (4**-p + 1 + 0.25**-p) ** (1 / p)
        assert float(soft_condition(M, p)) == pytest.approx(0.5 * np.log(ratio), abs=1e-14)
    # log cond(Y V) <= soft <= log cond(Y V) + log(r) / p, for a random SPD matrix
    g = torch.Generator().manual_seed(3)
    A = torch.randn(6, 6, generator=g, dtype=torch.float64)
    M = A @ A.T + 0.1 * torch.eye(6, dtype=torch.float64)
    exact = float(criterion_value(M, "condition"))
    for p in (2.0, 8.0, 64.0):
        soft = float(soft_condition(M, p))
        assert exact - 1e-12 <= soft <= exact + np.log(6) / p + 1e-12
    assert soft_condition(torch.zeros(2, 2, dtype=torch.float64), 4.0) == float("inf")
    with pytest.raises(ValueError, match="p must be positive"):
        soft_condition(M, 0.0)


def test_default_polish_lowers_the_condition_number_of_the_d_optimum():
    model = _model("head")
    limits = limits_from_model(model, velocity=1.0)
    kw = {**SMALL, "max_iter": 20, "polish_iter": 20}
    d = optimize_excitation(model, limits, rate=RATE, seed=0, criterion="d", **kw)
    dc = optimize_excitation(model, limits, rate=RATE, seed=0, **kw)  # the default
    assert dc.criterion == "d+condition"
    assert dc.start_values == d.start_values  # the same D-optimal starts, then the polish
    assert dc.condition_number < d.condition_number
    assert min(check_limits(model, dc.trajectory, limits, rate=RATE).values()) >= 0.0
    with pytest.raises(ValueError, match="needs at least one exponent"):
        optimize_excitation(model, limits, condition_p=(), **SMALL)
    with pytest.raises(ValueError, match="condition_p must be positive"):
        optimize_excitation(model, limits, condition_p=(2.0, -1.0), **SMALL)


def test_polish_never_raises_the_exact_condition_number_of_its_start():
    # one iteration at p = 2 is a poor polish: the kept trajectory must still be no worse, in
    # the exact condition number on the coarse grid, than the best D-optimal start; a second
    # polished start only adds candidates, so it is no worse than the first alone
    model = _model("head")
    limits = limits_from_model(model, velocity=1.0)
    kw = {**SMALL, "max_iter": 20, "n_starts": 2}
    d = optimize_excitation(model, limits, rate=RATE, seed=0, criterion="d", **kw)
    res = {
        (n, p): optimize_excitation(
            model,
            limits,
            rate=RATE,
            seed=0,
            condition_p=(2.0, math.inf),
            polish_starts=n,
            **{**kw, "polish_iter": p},
        )
        for n, p in ((1, 1), (2, 1), (1, 20))
    }
    assert d.shrink == 1.0 and all(r.shrink == 1.0 for r in res.values())  # coarse = reported
    for r in res.values():
        assert r.condition_number <= d.condition_number * (1 + 1e-12)
    assert res[2, 1].condition_number <= res[1, 1].condition_number * (1 + 1e-12)
    assert res[1, 1].start_values == d.start_values
    for bad in ({"polish_iter": 0}, {"polish_starts": 0}, {"polish_iter": 2.5}):
        name = next(iter(bad))
        with pytest.raises(ValueError, match=f"{name} must be a positive int"):
            optimize_excitation(model, limits, **{**SMALL, **bad})
    with pytest.raises(ValueError, match="condition_p must be positive"):
        optimize_excitation(model, limits, condition_p=(math.nan,), **SMALL)


def test_candidates_are_scaled_exactly_into_the_joint_limits_on_the_dense_grid():
    # the closed-form scale about the posture puts the binding joint limit exactly _EDGE inside
    # on the dense grid (checked by constraint_violations, the penalty's code), and the design
    # penalises the joint limits there, torques and workspace on the coarse grid
    model = _model("head")
    limits = limits_from_model(model, velocity=1.0, acceleration=3.0)
    q0 = 0.5 * (limits.position_low + limits.position_high)
    problem = _design._Design(model, limits, None, "d", None, None, period_grid(4.0, 60), q0, 0.25)
    assert problem.t_dense.numel() == 600
    g = torch.Generator().manual_seed(3)
    a, b = (torch.randn(7, 3, generator=g, dtype=torch.float64) for _ in range(2))
    for size in (3.0, 1e-3):  # beyond the limits: scaled to them; well inside: left as it is
        a_raw, b_raw = size * a, size * b
        s = problem.joint_scale(a_raw, b_raw)
        problem.scale_into_joint_limits(a_raw, b_raw)
        dense = fourier_states(
            problem.t_dense, problem.posture, *constrain_coefficients(a_raw, b_raw), 0.25
        )
        viol = constraint_violations(model, limits, *dense, kinds=_design.JOINT_KINDS)
        worst = max(float(v.max()) for v in viol.values())
        if size > 1:
            assert 0.0 < s < 1.0
            assert worst == pytest.approx(-_design._EDGE, abs=1e-12)
        else:
            assert s == 1.0 and worst < -0.4  # the posture: 0.5 of the range from both ends
    assert set(viol) == {"position", "velocity", "acceleration"}
    with pytest.raises(ValueError, match="unknown kinds of limit"):
        constraint_violations(model, limits, *dense, kinds=("speed",))
    # the optimiser's result needs no shrink for joint limits and uses them to the edge
    res = optimize_excitation(model, limits, rate=RATE, seed=0, **SMALL)
    assert res.shrink == 1.0
    assert 0.0 <= min(res.margins.values()) <= 2 * _design._EDGE


def test_the_polish_moves_each_limits_target_by_its_worst_excess():
    # update_shift: each limit's (column's) shift grows by the worst excess over its target
    # (_SAFETY inside the limit) and shrinks, not below 0, by the worst room left; the
    # penalty then aims that much further inside. Written out from the dense-grid states.
    model = _model("head")
    limits = limits_from_model(model, velocity=1.0, acceleration=math.inf)
    q0 = 0.5 * (limits.position_low + limits.position_high)
    V = base_directions(model, limits, generator=torch.Generator().manual_seed(0))
    problem = _design._Design(model, limits, V, "d", None, None, period_grid(4.0, 60), q0, 0.25)
    g = torch.Generator().manual_seed(4)
    size = torch.linspace(0.05, 0.6, 7, dtype=torch.float64)[:, None]  # per joint
    a_raw, b_raw = (size * torch.randn(7, 3, generator=g, dtype=torch.float64) for _ in range(2))
    a, b = constrain_coefficients(a_raw, b_raw)
    qd = fourier_states(problem.t_dense, problem.posture, a, b, 0.25)[1].numpy()
    excess = np.abs(qd).max(0) / 1.0 - 1.0 + _design._SAFETY["velocity"]  # velocity limit 1
    assert excess.max() > 0 > excess.min()  # some joints beyond, some inside
    problem.update_shift(a_raw, b_raw)
    np.testing.assert_allclose(problem.shift["velocity"].numpy(), np.maximum(excess, 0), atol=1e-12)
    problem.update_shift(a_raw, b_raw)  # the same motion again: the shifts add up
    np.testing.assert_allclose(problem.shift["velocity"].numpy(), np.maximum(2 * excess, 0),
                               atol=1e-12)  # fmt: skip
    # the penalty aims at the moved targets: each shift added to its limit's excess
    _, viol = problem.evaluate(0.5 * a_raw, 0.5 * b_raw)
    moved = {k: v + problem.shift[k] for k, v in viol.items()}
    expected = sum(
        (torch.relu(v + _design._SAFETY[k]) ** 2).mean(0).sum() for k, v in moved.items()
    )
    assert float(_design._penalty(viol, problem.shift)) == pytest.approx(float(expected), abs=0)
    assert float(_design._penalty(viol, problem.shift)) > float(_design._penalty(viol, {}))


def test_criteria_written_out():
    M = torch.diag(torch.tensor([4.0, 1.0, 0.25], dtype=torch.float64))
    assert float(criterion_value(M, "d")) == pytest.approx(-np.log(4 * 1 * 0.25) / 3, abs=1e-14)
    assert float(criterion_value(M, "condition")) == pytest.approx(np.log(4.0), abs=1e-14)
    assert float(criterion_value(M, "d+condition")) == pytest.approx(np.log(4.0), abs=1e-14)
    assert float(criterion_value(M, "e")) == pytest.approx(-np.log(0.25), abs=1e-14)
    assert criterion_value(torch.zeros(2, 2, dtype=torch.float64)) == float("inf")


def test_base_directions_span_what_the_regressor_sees():
    model = _model("head")
    limits = limits_from_model(model)
    V = base_directions(model, limits, generator=torch.Generator().manual_seed(0))
    assert V.shape[0] == model.n_params and 0 < V.shape[1] < model.n_params
    torch.testing.assert_close(V.T @ V, torch.eye(V.shape[1], dtype=torch.float64))
    # a regressor at other random states has (numerically) no component outside span(V)
    g = torch.Generator().manual_seed(5)
    q = torch.rand(50, 7, generator=g, dtype=torch.float64) - 0.5
    Y = model.regressor(q, torch.randn_like(q), torch.randn_like(q)).reshape(-1, model.n_params)
    outside = Y - (Y @ V) @ V.T
    assert float(outside.abs().max()) < 1e-9 * float(Y.abs().max())


def test_random_baseline_is_inside_the_same_limits_and_worse():
    model = _model("head")
    limits = limits_from_model(model, velocity=1.0)
    res = optimize_excitation(model, limits, rate=RATE, seed=0, **{**SMALL, "max_iter": 20})
    rnd = random_excitation(model, limits, base_frequency=0.25, harmonics=3, rate=RATE, seed=0)
    margins = check_limits(model, rnd, limits, rate=RATE)  # raises if violated
    assert min(margins.values()) >= 0.0
    opt = trajectory_information(model, res.trajectory, res.basis)
    base = trajectory_information(model, rnd, res.basis)
    assert opt["d"] < base["d"]


def test_limits_read_from_the_urdf_with_margin_and_overrides():
    model = _model("panda")
    limits = limits_from_model(model, position_margin=0.1, torque={"panda_joint7": 5.0})
    # panda_arm.urdf: joint1 lower -2.8973 upper 2.8973 velocity 2.175 effort 87; joint7 effort 12
    span = 2 * 2.8973
    assert limits.position_low[0] == pytest.approx(-2.8973 + 0.1 * span, abs=1e-12)
    assert limits.position_high[0] == pytest.approx(2.8973 - 0.1 * span, abs=1e-12)
    # the description's velocity less the default 15 % margin, reached from rest in 0.5 s
    assert limits.velocity[0] == pytest.approx(0.85 * 2.175)
    assert limits.acceleration[0] == pytest.approx(0.85 * 2.175 / 0.5)
    assert limits.torque[0] == pytest.approx(87.0)
    assert limits.torque[6] == pytest.approx(5.0)
    with pytest.raises(ValueError, match="unknown joints"):
        limits_from_model(model, velocity={"elbow": 1.0})
    with pytest.raises(ValueError, match="position_margin"):
        limits_from_model(model, position_margin=0.5)


def test_adam_and_other_criteria_run_and_hold_the_limits():
    model = _model("head")
    limits = limits_from_model(model, velocity=1.0)
    for kind in ("condition", "e"):
        res = optimize_excitation(model, limits, rate=RATE, criterion=kind, optimizer="adam",
                                  **{**SMALL, "max_iter": 10})  # fmt: skip
        assert res.criterion == kind
        assert min(check_limits(model, res.trajectory, limits, rate=RATE).values()) >= 0.0
