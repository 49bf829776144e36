"""Real logs as robots record them: several logs in one identification, motor currents with
drive gains, the rest at the ends dropped, the held-out target, and `evaluate` on other logs."""

import json
import warnings

import numpy as np
import pytest
import torch

import torchjfa
from torchjfa.cli import main
from torchjfa.data import JointLog, motion_span, prepare, read_log, write_log
from torchjfa.data._rest import REST_WINDOW_S
from torchjfa.identification import IdentificationWarning, evaluate
from torchjfa.sim import generate_log

CUTOFF = 15.0
#: fast and deterministic: a given cut-off and Coulomb velocity, plain least squares
PLAIN = {
    "cutoff": CUTOFF,
    "coulomb_velocity": 0.05,
    "jackknife": 0,
    "bias_correction": 0,
    "project": False,
    "description_prior": None,
    "weighting": "none",
    "input_noise": "learn",
    "period": None,
}


def _raw(log) -> JointLog:
    """A simulated log as a robot records it: t, q, qd, tau (no truth, no accelerations)."""
    return JointLog(t=log.t, q=log.q, qd=log.qd, tau=log.tau, joint_names=log.joint_names)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("several")
    paths = []
    for seed, n in ((0, 2100), (1, 1680), (2, 1680)):
        path = folder / f"head_{seed}.csv"
        write_log(_raw(generate_log("head", n_samples=n, seed=seed, progress=False)), path)
        paths.append(path)
    return paths


def _identify(robot, logs, validation_log=None, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        return torchjfa.identify(
            robot, logs, torchjfa.Options(**options), validation_log=validation_log
        )


def test_several_logs_sum_their_moments_each_prepared_on_its_own(logs):
    """The estimate from two logs is least squares on both logs' training rows, each log
    filtered on its own time base and split on its own (the last 20 %, the filter's reach
    apart): not one log with a jump in time."""
    ident = _identify("head", logs[:2], **PLAIN, trim_rest=False)
    model = ident.model
    rows, taus, n_held = [], [], 0
    for path in logs[:2]:
        data = prepare(read_log(path).reorder(model.joint_names), cutoff_hz=CUTOFF, period_s=None)
        gap = int(4.0 / CUTOFF * data.info["rate_hz"])
        n_tail = int(round(0.2 * data.n_samples))
        head = slice(0, data.n_samples - n_tail - gap)
        Y = model.regressor(data.q[head], data.qd[head], data.qdd[head])
        rows.append(Y.reshape(-1, model.n_params).numpy())
        taus.append(data.tau[head].reshape(-1).numpy())
        n_held += n_tail
    Y, tau = np.concatenate(rows), np.concatenate(taus)
    want = np.linalg.lstsq(Y, tau, rcond=1e-15)[0]  # keep every direction it can
    got = ident.result.theta_hat.numpy()
    # the description has directions the data barely see, which the two solvers truncate
    # differently: compare the residual sums of squares, the least-squares optimum's value (a
    # fit on other rows misses it by about n_params / n_rows = 5e-3 of it)
    rss_want, rss_got = (float(np.sum((Y @ th - tau) ** 2)) for th in (want, got))
    assert abs(rss_got - rss_want) <= 1e-6 * rss_want
    assert ident.data.validation.n_samples == n_held
    per_log = ident.report.settings["logs"]
    assert [r["log"] for r in per_log] == [str(p) for p in logs[:2]]
    assert all(r["held_out_samples"] > 0 and r["train_samples"] > 0 for r in per_log)
    assert all(len(r["nmse"]) == model.n_dof for r in per_log)
    # each log's own error: its held-out samples against its measured torque
    from torchjfa.identification import measured_torque
    from torchjfa.report import predicted_torques, torque_errors

    for record, part in zip(per_log, ident.data.parts, strict=True):
        v = part.validation
        tau = measured_torque(part.raw, v.t)
        pred = predicted_torques(model, ident.theta, v.q, v.qd, v.qdd, tau)
        nmse, _ = torque_errors(tau, pred)
        assert record["nmse"] == pytest.approx(nmse.tolist(), rel=1e-12)


def test_motor_currents_with_drive_gains_identify_as_the_torques_do(logs, tmp_path, capsys):
    """A log of currents with the gains gives the identification of the same log converted to
    torques beforehand; a wrong number of gains ends with one line and exit status 2."""
    log = read_log(logs[0])
    gains = torch.linspace(8.0, 11.0, log.n_dof, dtype=torch.float64)
    cols = {"t": log.t.numpy()}
    for i, j in enumerate(log.joint_names):
        cols[f"q_{j}"] = log.q[:, i].numpy()
        cols[f"qd_{j}"] = log.qd[:, i].numpy()
        cols[f"i_{j}"] = (log.tau[:, i] / gains[i]).numpy()
    currents = tmp_path / "currents.csv"
    import pyarrow as pa
    from pyarrow import csv

    csv.write_csv(pa.table(cols), currents)
    by_name = dict(zip(log.joint_names, gains.tolist(), strict=True))
    torques = _identify("head", logs[0], **PLAIN)
    order = [by_name[j] for j in torques.model.joint_names]  # the robot's joint order
    from_currents = _identify("head", currents, drive_gains=order, **PLAIN)
    a, b = torques.result.theta_hat, from_currents.result.theta_hat
    assert torch.allclose(a, b, rtol=0, atol=1e-9 * float(a.abs().max()))
    flag = ",".join(f"{g:.17g}" for g in order)
    out = tmp_path / "rep"
    args = ["identify", "head", str(currents), "--out", str(out), "--quiet", "--no-plots"]
    args += ["--cutoff", str(CUTOFF), "--jackknife", "0", "--no-project"]
    assert main([*args, "--drive-gains", flag]) == 0
    capsys.readouterr()
    assert main([*args, "--drive-gains", "10,10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "2 drive gains for the 7 joints" in err[0]
    assert main([*args]) == 2  # currents without gains
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "drive" in err[0]


def _with_rest(log: JointLog, seconds: float) -> JointLog:
    """``log`` with ``seconds`` of standing still (the first and last pose, zero velocity,
    the first and last torque) before and after it."""
    step = float(log.t[1] - log.t[0])
    n = int(round(seconds / step))
    t = torch.cat(
        [
            log.t[0] - step * torch.arange(n, 0, -1, dtype=torch.float64),
            log.t,
            log.t[-1] + step * torch.arange(1, n + 1, dtype=torch.float64),
        ]
    )

    def pad(x, zero=False):
        a = torch.zeros_like(x[:1]) if zero else x[:1]
        b = torch.zeros_like(x[-1:]) if zero else x[-1:]
        return torch.cat([a.expand(n, -1), x, b.expand(n, -1)])

    return JointLog(
        t=t,
        q=pad(log.q),
        qd=pad(log.qd, zero=True),
        tau=pad(log.tau),
        joint_names=log.joint_names,
    )


def test_rest_at_the_ends_is_dropped_and_reported(logs, tmp_path):
    """Seconds of standing still before and after the motion are dropped (all but the
    filter's reach), the report says how much, and the held-out end is motion, not rest."""
    log = read_log(logs[0])
    span = motion_span(log)
    padded = tmp_path / "rest.csv"
    write_log(_with_rest(log, 3.0), padded)
    ident = _identify("head", padded, **PLAIN)
    (record,) = ident.report.settings["logs"]
    start, end = record["rest_dropped_s"]
    step = float(log.t[1] - log.t[0])
    # the speed is averaged over a centred window: the motion shows half a window early
    reach = REST_WINDOW_S / 2 + 2 * step
    assert start == pytest.approx(3.0 + span.rest_start_s, abs=reach)
    assert end == pytest.approx(3.0 + span.rest_end_s, abs=reach)
    held = ident.data.validation
    reach = 4.0 / CUTOFF + REST_WINDOW_S
    moving = held.qd.abs().max(1).values > 0.05 * float(held.qd.abs().max())
    assert float(moving.float().mean()) > 0.95  # not rest
    edge = REST_WINDOW_S / 2 + 2 * step  # the padding is gone at both ends, but for that
    assert float(held.t[-1]) <= float(log.t[-1]) + edge
    assert float(ident.data.train.t[0]) >= float(log.t[0]) - edge
    assert ident.data.parts[0].raw.duration <= log.duration + 2 * reach + 2 * step
    report = (tmp_path / "rep").mkdir() or ident.write(tmp_path / "rep", plots=False)
    assert "rest dropped" in report["markdown"].read_text()
    # standing still throughout identifies nothing: one clear error
    still = JointLog(
        t=log.t,
        q=log.q[:1].expand_as(log.q),
        qd=0 * log.qd,
        tau=log.tau,
        joint_names=log.joint_names,
    )
    with pytest.raises(torchjfa.data.LogError, match="moves|move"):
        _identify("head", still, **PLAIN)


def test_the_held_out_target_is_the_measured_torque_whatever_the_cutoff(logs):
    """Runs at two cut-offs are judged on the same target: the log's torque as measured."""
    raw = read_log(logs[1])
    targets = []
    for cutoff in (5.0, 20.0):
        ident = _identify("head", logs[0], validation_log=logs[1], **{**PLAIN, "cutoff": cutoff})
        v = ident.report.validation
        idx = torch.searchsorted(raw.t, v.t)
        assert torch.equal(raw.t[idx], v.t)
        perm = [raw.joint_names.index(j) for j in v.joint_names]
        assert torch.equal(v.tau, raw.tau[idx][:, perm])
        assert "unfiltered" in ident.report.settings["held_out_target"]
        targets.append(dict(zip(v.t.tolist(), v.tau.tolist(), strict=True)))
    common = set(targets[0]) & set(targets[1])
    assert len(common) > 100
    assert all(targets[0][t] == targets[1][t] for t in common)


def test_evaluate_judges_a_saved_model_on_other_logs(logs, tmp_path, capsys):
    """``torchjfa evaluate MODEL LOG...`` prepares each log at the model's own cut-off and
    judges it against the measured torque: on the held-out log of the identification it
    gives the report's numbers; the JSON has the identified and the description's errors."""
    ident = _identify("head", logs[0], validation_log=logs[1], **PLAIN)
    paths = ident.write(tmp_path / "rep", plots=False)
    ev = evaluate(paths["model"], logs[1], torchjfa.Options(**PLAIN))
    assert ev.cutoff_hz == CUTOFF
    want = ident.report.fits["identified"]
    got = ev.fits["identified"]
    assert torch.allclose(got.rms, want.rms, rtol=1e-10, atol=0)
    assert torch.allclose(got.nmse, want.nmse, rtol=1e-10, atol=0)
    out = tmp_path / "ev"
    assert (
        main(["evaluate", str(paths["model"]), str(logs[1]), str(logs[2]), "--out", str(out)]) == 0
    )
    summary = json.loads((out / "evaluation.json").read_text())
    assert summary["joint_names"] == list(ident.model.joint_names)
    for key in ("rms", "mean_rms", "nmse", "mean_nmse"):
        assert key in summary and key in summary["description"]
    assert len(summary["logs"]) == 2 and (out / "torques_1.png").is_file()
    assert summary["mean_rms"] < summary["description"]["mean_rms"]
    capsys.readouterr()
    assert main(["evaluate", str(paths["model"])]) == 2
    assert main(["evaluate", str(tmp_path / "none.npz"), str(logs[1])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("torchjfa evaluate: error:") for line in err)


def test_a_torque_channel_with_the_wrong_sign_is_named(logs, tmp_path):
    """A joint whose torque was recorded with the opposite sign is named in one warning; the
    log as recorded gets none."""
    log = read_log(logs[0])
    assert not any("runs against" in w for w in _identify("head", log, **PLAIN).warnings)
    j = log.joint_names.index("neck_tilt")
    tau = log.tau.clone()
    tau[:, j] *= -1
    flipped = JointLog(t=log.t, q=log.q, qd=log.qd, tau=tau, joint_names=log.joint_names)
    lines = [w for w in _identify("head", flipped, **PLAIN).warnings if "runs against" in w]
    assert len(lines) == 1 and "neck_tilt" in lines[0]
    others = [n for n in log.joint_names if n != "neck_tilt"]
    assert not any(f"{n} (" in lines[0] for n in others)
