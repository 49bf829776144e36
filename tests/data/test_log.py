"""Reading joint logs: formats, column mapping, joint matching, and the errors a person sees."""

import numpy as np
import pytest
import torch

from torchjfa.data import JointLog, LogError, read_log, write_log

JOINTS = ("shoulder", "elbow_joint", "wrist")


def _log(n=50, seed=0, qd=True):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    return JointLog(
        t=t,
        q=rng.standard_normal((n, 3)),
        qd=rng.standard_normal((n, 3)) if qd else None,
        tau=rng.standard_normal((n, 3)),
        joint_names=JOINTS,
    )


@pytest.mark.parametrize("suffix", [".csv", ".npz", ".parquet"])
def test_round_trip_every_format(tmp_path, suffix):
    log = _log()
    path = tmp_path / f"log{suffix}"
    write_log(log, path)
    back = read_log(path)
    assert back.joint_names == JOINTS
    for k in ("t", "q", "qd", "tau"):
        torch.testing.assert_close(getattr(back, k), getattr(log, k), rtol=0, atol=1e-15)
    assert back.qdd is None


def test_csv_written_by_hand_with_mapping_and_any_column_order(tmp_path):
    """A robot's own column names, time in ns, joints in another order than the model's."""
    log = _log(qd=False)
    cols = {"stamp_ns": (log.t.numpy() * 1e9).round()}
    header = {"q": "pos", "tau": "effort"}
    for kind in ("tau", "q"):
        for i, j in reversed(list(enumerate(JOINTS))):
            cols[f"{header[kind]}.{j}"] = getattr(log, kind)[:, i].numpy()
    path = tmp_path / "robot.csv"
    names = list(cols)
    data = np.column_stack([cols[c] for c in names])
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt="%.17g")
    mapping = {"t": "stamp_ns"}
    mapping.update({f"{k}_{j}": f"{header[k]}.{j}" for k in header for j in JOINTS})
    back = read_log(path, columns=mapping, time_scale=1e-9)
    assert set(back.joint_names) == set(JOINTS)
    aligned = back.reorder(JOINTS)
    assert aligned.joint_names == JOINTS
    torch.testing.assert_close(aligned.q, log.q, rtol=0, atol=1e-12)
    torch.testing.assert_close(aligned.tau, log.tau, rtol=0, atol=1e-12)
    torch.testing.assert_close(aligned.t, log.t, rtol=0, atol=1e-9)
    assert aligned.qd is None


def test_matrix_npz_of_the_simulator_is_read(tmp_path):
    log = _log()
    path = tmp_path / "m.npz"
    np.savez(
        path,
        t=log.t.numpy(),
        q=log.q.numpy(),
        qd=log.qd.numpy(),
        qdd=log.q.numpy() * 2,
        tau=log.tau.numpy(),
        joint_names=np.array(JOINTS),
    )
    back = read_log(path)
    assert back.joint_names == JOINTS
    torch.testing.assert_close(back.qdd, log.q * 2)


def test_reorder_rejects_unknown_and_missing_joints():
    log = _log()
    with pytest.raises(LogError, match=r"\['wrist'\] are in the log but the robot has no joint"):
        log.reorder(("shoulder", "elbow_joint", "hand"))
    with pytest.raises(LogError, match=r"robot's joint\(s\) \['hand'\] have no columns"):
        log.select(slice(None)).reorder(("shoulder", "elbow_joint", "wrist", "hand"))


def _write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(r) for r in rows) + "\n")


def test_missing_column_names_it(tmp_path):
    path = tmp_path / "a.csv"
    _write_csv(path, ["t", "q_a", "q_b", "tau_a"], [["0", "1", "2", "3"], ["1", "1", "2", "3"]])
    with pytest.raises(LogError, match="missing column 'tau_b'"):
        read_log(path)
    _write_csv(path, ["time", "q_a", "tau_a"], [["0", "1", "3"], ["1", "1", "3"]])
    with pytest.raises(LogError, match="missing column 't'"):
        read_log(path)
    with pytest.raises(LogError, match="names 'stamp'"):
        read_log(path, columns={"t": "stamp"})
    assert read_log(path, columns={"t": "time"}).n_samples == 2


def test_nan_rows_are_reported_then_dropped_on_request(tmp_path):
    rows = [[str(i * 0.01), str(np.sin(i)), str(i)] for i in range(20)]
    rows[3][1] = "nan"
    rows[11][2] = ""
    path = tmp_path / "n.csv"
    _write_csv(path, ["t", "q_a", "tau_a"], rows)
    with pytest.raises(LogError, match=r"2 of 20 rows hold NaN or inf \(rows 3, 11,"):
        read_log(path)
    back = read_log(path, drop_nan=True)
    assert back.n_samples == 18
    assert bool(torch.isfinite(back.q).all())


def test_time_must_increase(tmp_path):
    path = tmp_path / "b.csv"
    rows = [["0", "0", "0"], ["0.1", "0", "0"], ["0.05", "0", "0"], ["0.2", "0", "0"]]
    _write_csv(path, ["t", "q_a", "tau_a"], rows)
    with pytest.raises(LogError, match="time must increase strictly, but at row 2"):
        read_log(path)


def test_partial_velocity_columns_and_text_columns_are_errors(tmp_path):
    path = tmp_path / "c.csv"
    _write_csv(
        path,
        ["t", "q_a", "q_b", "qd_a", "tau_a", "tau_b"],
        [["0", "0", "0", "0", "0", "0"], ["1", "0", "0", "0", "0", "0"]],
    )
    with pytest.raises(LogError, match=r"qd columns for some joints but not for \['qd_b'\]"):
        read_log(path)
    # the joints were found in the columns: the message says they may be a stranger's
    with pytest.raises(LogError, match=r"if \['b'\] are not joints of the robot, remove"):
        read_log(path)
    with pytest.raises(LogError, match=r"none$"):  # joints given: no such guess
        read_log(path, joints=["a", "b"])
    _write_csv(path, ["t", "q_a", "tau_a"], [["0", "x", "0"], ["1", "y", "0"]])
    with pytest.raises(LogError, match="column 'q_a' is not numeric"):
        read_log(path)


def test_unknown_format_and_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_log(tmp_path / "none.csv")
    p = tmp_path / "x.dat"
    p.write_text("t\n")
    with pytest.raises(LogError, match="format"):
        read_log(p)


def test_split_keeps_order_and_gap():
    log = _log(n=100)
    head, tail = log.split(0.2, gap=5)
    assert tail.n_samples == 20 and head.n_samples == 75
    torch.testing.assert_close(tail.t, log.t[80:])
    torch.testing.assert_close(head.q, log.q[:75])
    with pytest.raises(LogError):
        log.split(1.5)
