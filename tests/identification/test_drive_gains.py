"""`identify_drive_gains`: per-joint torque scales (drive gains) from a payload of known mass, on
the 2R arm of the payload tests, whose point-mass payload torques are written by hand there.

The logs' torque columns are the true torques divided by a per-joint scale ``c`` (a drive
gain the logs were read with wrongly, or a torque sensor's scale error): the fit must return
``c``. An equation-error fit (``c u = Y theta + Z pi`` by least squares) prefers gains that are
too small, and the check below says by how much it would miss on the same data.
"""

import pytest
import torch
from test_payload import ARM, MASS, _log

from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import IdentificationError, Options, identify_drive_gains
from torchjfa.identification._payload import payload_regressor

SCALES = (1.3, 0.8)


def _scaled(log, scales):
    from dataclasses import replace

    return replace(log, tau=log.tau / torch.tensor(scales, dtype=torch.float64))


def _noisy(log, seed, level):
    from dataclasses import replace

    g = torch.Generator().manual_seed(seed)
    noise = (
        level * log.tau.abs().mean(0) * torch.randn(log.tau.shape, generator=g, dtype=torch.float64)
    )
    return replace(log, tau=log.tau + noise)


@pytest.fixture(scope="module")
def arm():
    model = RigidBodyModel.from_urdf(ARM, friction=("viscous",))
    theta = model.nominal_theta.clone()
    theta[model.layout.split(torch.arange(model.n_params))[1].flatten()] = 0.2  # viscous
    return model, theta


def test_the_scales_of_noiseless_logs_are_recovered(arm):
    model, theta = arm
    loaded = _scaled(_log(model, theta), SCALES)
    free = _scaled(_log(model, theta, loaded=False, shift=0.7, seconds=15.0), SCALES)
    # the identified robot the fit starts from is 30 % off: it is fitted again
    found = identify_drive_gains(
        (model, theta * 1.3),
        loaded,
        free,
        link="tool",
        mass=MASS,
        options=Options(cutoff=20.0),
        blocks=4,
    )
    # the filter's and the differences' errors only (the payload test's 1e-3 on the mass)
    assert found.gains.tolist() == pytest.approx(list(SCALES), rel=2e-3)
    assert torch.equal(found.nominal, torch.ones(2, dtype=torch.float64))
    assert bool(found.determined.all())
    assert float(found.payload[0]) == MASS
    assert float((found.std / found.gains).max()) < 2e-3
    # unweighted (options.weighting), the noiseless logs give the same scales
    plain = identify_drive_gains(
        (model, theta * 1.3),
        loaded,
        free,
        link="tool",
        mass=MASS,
        options=Options(cutoff=20.0, weighting="none", jackknife=4),
    )
    assert plain.gains.tolist() == pytest.approx(list(SCALES), rel=2e-3)
    assert plain.std.shape == (2,) and bool((plain.std > 0).all())


def test_noisy_logs_give_the_scales_within_their_spreads_where_least_squares_shrinks_them(arm):
    """10 % torque noise: the current-error fit lands within 4 jackknife spreads of the truth;
    equation-error least squares on the same rows (unconstrained, by hand here) lands lower."""
    model, theta = arm
    loaded = _noisy(_scaled(_log(model, theta, seconds=40.0), SCALES), 0, 0.1)
    free = _noisy(
        _scaled(_log(model, theta, loaded=False, shift=0.7, seconds=40.0), SCALES), 1, 0.1
    )
    options = Options(cutoff=20.0)
    found = identify_drive_gains(
        (model, theta), loaded, free, link="tool", mass=MASS, options=options
    )
    truth = torch.tensor(SCALES, dtype=torch.float64)
    assert bool(((found.gains - truth).abs() <= 4 * found.std).all()), (found.gains, found.std)
    assert bool((found.std > 0).all())
    # the equation-error least squares: rows (Y, Z, -u e_j) x = 0 with the mass's column moved
    # to the right-hand side
    from torchjfa.data import prepare

    j, A = payload_regressor(model, "tool")
    cols = model.layout.split(torch.arange(model.n_params))[0][j]
    blocks = []
    for log, carries in ((loaded, True), (free, False)):
        p = prepare(log, cutoff_hz=20.0, period_s=None)
        Y = model.regressor(p.q, p.qd, p.qdd)
        Z = Y[..., cols] @ A if carries else torch.zeros(*Y.shape[:2], 10, dtype=Y.dtype)
        blocks.append(torch.cat([Y, Z, -torch.diag_embed(p.tau)], -1).reshape(-1, Y.shape[-1] + 12))
    X = torch.cat(blocks)
    rhs = -X[:, model.n_params] * MASS
    keep = [k for k in range(X.shape[1]) if k != model.n_params]
    sol = torch.linalg.lstsq(X[:, keep], rhs.unsqueeze(1), driver="gelsd").solution.flatten()
    shrunk = sol[-2:]
    assert float(((shrunk - truth) / truth).min()) < float(((found.gains - truth) / truth).min())


def test_bad_input_is_refused(arm):
    model, theta = arm
    log = _log(model, theta)
    with pytest.raises(IdentificationError, match="mass must be positive"):
        identify_drive_gains((model, theta), log, log, link="tool", mass=0.0)
    with pytest.raises(IdentificationError, match="blocks"):
        identify_drive_gains((model, theta), log, log, link="tool", mass=1.0, blocks=2)
    with pytest.raises(IdentificationError, match="options.jackknife"):
        options = Options(jackknife=0)  # the spreads' blocks come from the options
        identify_drive_gains((model, theta), log, log, link="tool", mass=1.0, options=options)
    with pytest.raises(IdentificationError, match="no frame"):
        identify_drive_gains((model, theta), log, log, link="nosuch", mass=1.0)


def test_the_command_writes_the_gains_and_needs_unloaded_runs(arm, tmp_path, capsys):
    import json

    from torchjfa.cli import main
    from torchjfa.data import write_log
    from torchjfa.io import save_identified

    model, theta = arm
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM)
    saved = RigidBodyModel.from_urdf(str(urdf), friction=("viscous",))
    save_identified(tmp_path / "model.npz", saved, theta, cutoff_hz=20.0)
    write_log(_scaled(_log(model, theta), SCALES), tmp_path / "loaded.csv")
    free = _log(model, theta, loaded=False, shift=0.7, seconds=15.0)
    write_log(_scaled(free, SCALES), tmp_path / "free.csv")
    args = ["payload", str(tmp_path / "model.npz"), str(tmp_path / "loaded.csv"), "--link", "tool"]
    out = tmp_path / "g"
    assert main([*args, "--mass", str(MASS), "--unloaded", str(tmp_path / "free.csv"),
                 "--out", str(out)]) == 0  # fmt: skip
    summary = json.loads((out / "drive_gains.json").read_text())
    gains = [summary["joints"][j]["gain"] for j in model.joint_names]
    assert gains == pytest.approx(list(SCALES), rel=2e-3)
    assert "--drive-gains" in capsys.readouterr().out
    assert main([*args, "--mass", str(MASS), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs --unloaded" in err[0]
