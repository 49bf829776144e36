"""`identify_payload` against a payload's torques written independently: a point mass fixed to a
tool frame of a planar 2R arm, its torques ``tau = J_p^T m (p'' - g)`` from the tip's position
``p(q)``, its Jacobian and acceleration by hand."""

import math

import pytest
import torch

from torchjfa.data import JointLog
from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import IdentificationError, Options
from torchjfa.identification._payload import (
    PARAMETERS,
    identify_payload,
    payload_regressor,
    transform_map,
)

L1, TOOL = 0.4, (0.25, 0.0, 0.05)  # the tool frame on link 2, m (x along the link, z up)
ARM = f"""<?xml version="1.0"?>
<robot name="two_link">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0.2 0 0"/><mass value="1.0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.15 0.0 0"/><mass value="0.5"/>
    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.006" iyz="0" izz="0.005"/></inertial></link>
  <link name="tool"/>
  <joint name="j1" type="continuous"><parent link="base"/><child link="l1"/>
    <axis xyz="0 1 0"/></joint>
  <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>
    <origin xyz="{L1} 0 0"/><axis xyz="0 1 0"/></joint>
  <joint name="flange" type="fixed"><parent link="l2"/><child link="tool"/>
    <origin xyz="{TOOL[0]} {TOOL[1]} {TOOL[2]}"/></joint>
</robot>
"""
MASS, COM = 1.7, (0.03, 0.0, 0.02)  # the payload: a point mass, its position in the tool frame


def _point_mass_torques(q, qd, qdd):
    """Joint torques of the point mass, by hand: rotations about y by q1 and q1 + q2 carry the
    x-z offsets; ``p = R(q1) [L1, 0] + R(q1 + q2) [TOOL + COM]`` in the x-z plane."""
    a = (L1, 0.0)
    b = (TOOL[0] + COM[0], TOOL[2] + COM[2])

    def rot(angle, v):  # rotation about +y: x' = x cos + z sin, z' = -x sin + z cos
        c, s = torch.cos(angle), torch.sin(angle)
        return v[0] * c + v[1] * s, -v[0] * s + v[1] * c

    def d_rot(angle, v):  # derivative of rot with respect to the angle
        c, s = torch.cos(angle), torch.sin(angle)
        return -v[0] * s + v[1] * c, -v[0] * c - v[1] * s

    q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
    # Jacobian columns of p (x, z)
    dA, dB = d_rot(q1, a), d_rot(q12, b)
    J1 = (dA[0] + dB[0], dA[1] + dB[1])
    J2 = dB
    # acceleration: p'' = J qdd + (second derivatives) qd qd
    w1, w12 = qd[:, 0], qd[:, 0] + qd[:, 1]
    A, B = rot(q1, a), rot(q12, b)
    ax = dA[0] * qdd[:, 0] + dB[0] * (qdd[:, 0] + qdd[:, 1]) - A[0] * w1**2 - B[0] * w12**2
    az = dA[1] * qdd[:, 0] + dB[1] * (qdd[:, 0] + qdd[:, 1]) - A[1] * w1**2 - B[1] * w12**2
    fx, fz = MASS * ax, MASS * (az + 9.81)  # the force the arm exerts on the mass
    return torch.stack([J1[0] * fx + J1[1] * fz, J2[0] * fx + J2[1] * fz], 1)


def _log(model, theta, *, loaded=True, shift=0.0, seconds=20.0, rate=200.0):
    """A smooth excitation (sums of sines), torques of the arm (and of the payload)."""
    t = torch.arange(int(seconds * rate), dtype=torch.float64) / rate
    w = 2 * math.pi * torch.tensor([0.23, 0.41, 0.67], dtype=torch.float64)
    amp = torch.tensor([[0.9, 0.4, 0.2], [1.1, 0.3, 0.25]], dtype=torch.float64)
    phase = torch.tensor([[0.0, 1.0, 2.0], [0.5, 1.5, 2.5]], dtype=torch.float64) + shift
    arg = w * t[:, None, None] + phase  # (n, 2, 3)
    q = (amp * torch.sin(arg)).sum(-1)
    qd = (amp * w * torch.cos(arg)).sum(-1)
    qdd = -(amp * w * w * torch.sin(arg)).sum(-1)
    tau = model.regressor(q, qd, qdd) @ theta
    if loaded:
        tau = tau + _point_mass_torques(q, qd, qdd)
    return JointLog(t=t, q=q, qd=qd, tau=tau, joint_names=model.joint_names)


def test_the_transform_map_moves_a_body_as_the_parallel_axis_theorem_says():
    T = torch.eye(4, dtype=torch.float64)
    T[:3, 3] = torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64)
    pi = torch.tensor([2.0, 0.0, 0.0, 0.1, 0.01, 0, 0.01, 0, 0, 0.02], dtype=torch.float64)
    moved = transform_map(T) @ pi
    # h: 2 kg at z = 0.05 + 0.1; Ixx about the new origin: (0.01 - 2 0.05^2) + 2 0.15^2
    assert moved[3] == pytest.approx(0.3, abs=1e-15)
    assert moved[4] == pytest.approx(0.01 - 2 * 0.05**2 + 2 * 0.15**2, abs=1e-15)
    assert moved[9] == pytest.approx(0.02, abs=1e-15)


def test_a_point_mass_on_the_tool_is_recovered():
    model = RigidBodyModel.from_urdf(ARM, friction=())
    joint, _ = payload_regressor(model, "tool")
    assert model.joint_names[joint] == "j2"
    theta = model.nominal_theta
    log = _log(model, theta)
    payload = identify_payload((model, theta), log, link="tool", options=Options(cutoff=20.0))
    # the log is smooth and noiseless: the filter's and the differences' errors only
    assert payload.mass == pytest.approx(MASS, rel=1e-3)
    assert payload.com[0] == pytest.approx(COM[0], abs=1e-3)
    assert payload.com[2] == pytest.approx(COM[2], abs=1e-3)
    assert float(payload.rms_with.max()) < 0.01 * float(payload.rms_without.max())
    # with an unloaded run of the same arm (another motion), the robot fitted again alongside:
    # a robot model that is wrong cancels
    wrong = theta * 1.3
    free = _log(model, theta, loaded=False, shift=0.7, seconds=15.0)
    pair = identify_payload(
        (model, wrong), log, link="tool", unloaded=free, options=Options(cutoff=20.0)
    )
    assert pair.mass == pytest.approx(MASS, rel=1e-3)
    alone = identify_payload((model, wrong), log, link="tool", options=Options(cutoff=20.0))
    assert abs(alone.mass - MASS) > 10 * abs(pair.mass - MASS)


def test_the_command_writes_the_payload_and_refuses_an_unknown_link(tmp_path, capsys):
    import json

    from torchjfa.cli import main
    from torchjfa.data import write_log
    from torchjfa.io import save_identified

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM)
    model = RigidBodyModel.from_urdf(str(urdf), friction=())
    save_identified(tmp_path / "model.npz", model, model.nominal_theta, cutoff_hz=20.0)
    write_log(_log(model, model.nominal_theta), tmp_path / "loaded.csv")
    args = ["payload", str(tmp_path / "model.npz"), str(tmp_path / "loaded.csv")]
    assert main([*args, "--link", "tool", "--out", str(tmp_path / "p")]) == 0
    summary = json.loads((tmp_path / "p" / "payload.json").read_text())
    assert summary["mass"] == pytest.approx(MASS, rel=1e-3)
    report = (tmp_path / "p" / "payload.md").read_text()
    assert report.startswith("# Payload on tool") and "| m |" in report
    # the description with the payload attached: reloaded, the payload is lumped into link 2
    loaded = RigidBodyModel.from_urdf(str(tmp_path / "p" / "robot_with_payload.urdf"), friction=())
    joint, A = payload_regressor(model, "tool")
    before, _ = model.layout.split(model.nominal_theta)
    after, _ = loaded.layout.split(loaded.nominal_theta)
    want = before[joint] + A @ torch.tensor(summary["theta"], dtype=torch.float64)
    assert torch.allclose(after[joint], want, rtol=1e-9, atol=1e-12)
    assert torch.equal(after[1 - joint], before[1 - joint])
    # the fit's options are Options' own: no jackknife, unweighted
    plain = ["--jackknife", "0", "--weighting", "none", "--out", str(tmp_path / "r")]
    assert main([*args, "--link", "tool", *plain]) == 0
    again = json.loads((tmp_path / "r" / "payload.json").read_text())
    assert again["mass"] == pytest.approx(MASS, rel=1e-3)
    assert "no jackknife spread" in (tmp_path / "r" / "payload.md").read_text()
    capsys.readouterr()
    assert main([*args, "--link", "nosuch", "--out", str(tmp_path / "q")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no frame 'nosuch'" in err[0]
    assert main([*args, "--link", "tool", "--bounds", "ball:1", "--out", str(tmp_path / "q")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sphere:R" in err[0]


def test_bounds_keep_the_payload_inside_a_region_the_user_gives():
    """The point mass sits 3.6 cm from the tool frame's origin; a sphere of 2 cm about the
    origin excludes it, so the bounded answer lies on the sphere (its condition active) and a
    box keeps the centre of mass inside; unbounded, the payload is where it is."""
    from torchjfa.identification._payload import Bounds

    model = RigidBodyModel.from_urdf(ARM, friction=())
    theta = model.nominal_theta
    log = _log(model, theta)
    options = Options(cutoff=20.0)
    free = identify_payload((model, theta), log, link="tool", options=options, bounds="sphere:0.1")
    assert free.com.tolist() == pytest.approx([COM[0], 0.0, COM[2]], abs=1e-3)
    inside = identify_payload(
        (model, theta), log, link="tool", options=options, bounds="sphere:0.02"
    )
    m, I_o = inside.theta[0], inside.theta[4:]  # I_o: xx, xy, yy, xz, yz, zz
    second = 0.5 * (I_o[0] + I_o[2] + I_o[5])  # int |x|^2 dm = tr(I_o) / 2
    assert float(second) <= float(m) * 0.02**2 * (1 + 1e-6)
    assert float(second) == pytest.approx(float(m) * 0.02**2, rel=1e-4)  # on the sphere
    assert float(inside.com.norm()) <= 0.02 * (1 + 1e-6)
    assert float(inside.rms_with.mean()) > float(free.rms_with.mean())  # the data disagree
    box = Bounds.parse("box:-0.01,-0.01,-0.01,0.01,0.01,0.01")
    boxed = identify_payload((model, theta), log, link="tool", options=options, bounds=box)
    assert float(boxed.com.abs().max()) <= 0.01 * (1 + 1e-6)
    assert "box:" in boxed.markdown() and boxed.summary()["bounds"] == str(box)
    for bad in ("sphere:-1", "box:0,0,0,0,1,1", "cube:1", "sphere:a"):
        with pytest.raises(IdentificationError, match="bounds"):
            Bounds.parse(bad)


def test_the_spreads_match_the_scatter_over_noise_draws():
    """White torque noise, filtered by the preparation (so neighbouring rows are correlated):
    the jackknife spread of the mass is within a factor 2 of the scatter of the estimates over
    noise draws, where least squares' row formula would be several times too small."""
    from dataclasses import replace

    model = RigidBodyModel.from_urdf(ARM, friction=())
    theta = model.nominal_theta
    clean = _log(model, theta, seconds=30.0)
    masses, spreads = [], []
    for seed in range(12):
        g = torch.Generator().manual_seed(seed)
        noisy = replace(
            clean,
            tau=clean.tau + 0.5 * torch.randn(clean.tau.shape, generator=g, dtype=torch.float64),
        )
        p = identify_payload((model, theta), noisy, link="tool", options=Options(cutoff=5.0))
        masses.append(float(p.theta_hat[0]))
        spreads.append(float(p.std[0]))
    scatter = float(torch.tensor(masses).std())
    spread = float(torch.tensor(spreads).mean())
    assert 0.5 < spread / scatter < 2.0, (spread, scatter)
    # a planar arm turning about y sees the mass, hx, hz and Iyy of its payload, nothing else
    seen = dict(zip(PARAMETERS, p.determined.tolist(), strict=True))
    assert seen["m"] and seen["hx"] and seen["hz"]
    assert not any(seen[k] for k in ("hy", "Ixx", "Ixy", "Ixz", "Iyz", "Izz"))
    assert "not determined by the logs" in p.markdown()


def test_a_noisy_joint_does_not_drown_a_quiet_one():
    """Joint 1's torque 20x noisier than joint 2's: weighting each joint's rows by its residual
    level (``weighting="residual"``, the default) finds the payload's mass and centre of mass
    closer to the truth, over noise draws, than treating every row alike (``"none"``)."""
    from dataclasses import replace

    model = RigidBodyModel.from_urdf(ARM, friction=())
    theta = model.nominal_theta
    clean = _log(model, theta, seconds=30.0)
    level = torch.tensor([2.0, 0.1], dtype=torch.float64)
    errors = {"residual": [], "none": []}
    for seed in range(8):
        g = torch.Generator().manual_seed(seed)
        noise = level * torch.randn(clean.tau.shape, generator=g, dtype=torch.float64)
        noisy = replace(clean, tau=clean.tau + noise)
        for weighting in errors:
            options = Options(cutoff=5.0, weighting=weighting)
            p = identify_payload((model, theta), noisy, link="tool", options=options)
            assert ("weighted by its residual level" in p.how) == (weighting == "residual")
            com = torch.tensor([COM[0], COM[2]], dtype=torch.float64)
            errors[weighting].append(
                ((p.theta_hat[0] - MASS) / MASS) ** 2
                + ((p.theta_hat[[1, 3]] / p.theta_hat[0] - com) / 0.01).pow(2).sum()
            )
    # the weights are 1 / sigma_j^2 with sigma_1 / sigma_2 = 20, well inside the floor
    # (JOINT_WEIGHT_FLOOR = 1e-3 of the variance, a ratio of about 32 in sigma)
    residual = float(torch.stack(errors["residual"]).mean())
    assert residual < 0.5 * float(torch.stack(errors["none"]).mean())


def test_the_options_estimator_fits_the_payload_rows_formed_by_hand():
    """Two paths, one answer: the payload's estimate from the streamed moments, mapped to its
    columns (``Z = Y_B A``, right-hand side ``tau - Y theta``), equals the options' estimator
    (ridge with a penalty that moves the answer) fitted on those rows formed by hand, with the
    joints unweighted and weighted by their inverse residual variances (mean 1)."""
    from dataclasses import replace

    from torchjfa.estimators import OLS, Ridge
    from torchjfa.identification._prepare import read_prepared, split_held_out

    model = RigidBodyModel.from_urdf(ARM, friction=())
    theta = model.nominal_theta
    clean = _log(model, theta)
    g = torch.Generator().manual_seed(3)
    level = torch.tensor([1.0, 0.1], dtype=torch.float64)
    noisy = replace(
        clean,
        tau=clean.tau + level * torch.randn(clean.tau.shape, generator=g, dtype=torch.float64),
    )
    _, data = read_prepared(noisy, model, Options(), 20.0)
    train, _ = split_held_out(data, Options().validation, 20.0)
    joint, A = payload_regressor(model, "tool")
    Y = model.regressor(train.q, train.qd, train.qdd)  # (n, 2, p)
    Z = Y[..., model.layout.split(torch.arange(model.n_params))[0][joint]] @ A  # (n, 2, 10)
    y = train.tau - Y @ theta  # (n, 2)
    ols = OLS(fit_intercept=False).fit(Z.reshape(-1, 10), y.reshape(-1)).coef_
    var = (y - Z @ ols).pow(2).mean(0)  # each joint's residual variance, well above the floor
    alpha = 0.01 * float(torch.einsum("nji,nji->", Z, Z)) / 10  # 1 % of the mean eigenvalue
    for weighting, w in (("none", torch.ones(2)), ("residual", (1 / var) / (1 / var).mean())):
        options = Options(
            cutoff=20.0,
            estimator="ridge",
            estimator_options={"alpha": alpha},
            weighting=weighting,
            jackknife=0,
        )
        found = identify_payload((model, theta), noisy, link="tool", options=options)
        root = w.to(torch.float64).sqrt()
        X, target = (Z * root[:, None]).reshape(-1, 10), (y * root).reshape(-1)
        want = Ridge(alpha=alpha, fit_intercept=False).fit(X, target).coef_
        # the same normal equations summed in another order: rounding only
        assert torch.allclose(
            found.theta_hat, want, rtol=1e-8, atol=1e-10 * float(want.abs().max())
        )
        unpenalised = OLS(fit_intercept=False).fit(X, target).coef_
        assert abs(float(want[0] - unpenalised[0])) > 1e-4 * MASS  # the penalty shows
        assert "estimator ridge" in found.how


def test_without_the_jackknife_there_are_no_spreads_and_the_motion_decides():
    model = RigidBodyModel.from_urdf(ARM, friction=())
    theta = model.nominal_theta
    found = identify_payload(
        (model, theta), _log(model, theta), link="tool", options=Options(cutoff=20.0, jackknife=0)
    )
    assert bool(found.std.isnan().all())
    assert found.mass == pytest.approx(MASS, rel=1e-3)
    seen = {n for n, ok in zip(PARAMETERS, found.determined.tolist(), strict=True) if ok}
    assert seen == {"m", "hx", "hz", "Iyy"}  # what a planar arm turning about y excites
    assert "no jackknife spread" in found.markdown()
