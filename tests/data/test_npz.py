"""The one ``.npz`` reader: the same arrays from every layout and compression, lazily."""

import numpy as np
import pytest
import torch

from torchjfa.data import JointLog, LogError, NpzArchive, NpzLog, log_sources, read_log, write_log
from torchjfa.sim import SensorNoise, SimulatedLog

JOINTS = ("j0", "j1", "j2")
SIGNALS = ("q", "qd", "qdd", "tau")


def _signals(n=203, seed=0):
    g = torch.Generator().manual_seed(seed)
    out = {k: torch.randn(n, 3, generator=g, dtype=torch.float64) for k in SIGNALS}
    out["t"] = torch.arange(n, dtype=torch.float64) / 100.0
    return out


def _simulated(sig):
    truth = {f"{k}_true": v + 1.0 for k, v in sig.items() if k != "t"}
    return SimulatedLog(
        robot="toy",
        joint_names=JOINTS,
        **sig,
        **truth,
        period_samples=50,
        control_rate=100.0,
        noise=SensorNoise(),
        seed=None,
    )


@pytest.fixture
def files(tmp_path):
    """The same log as matrices (uncompressed, compressed), a SimulatedLog file and columns."""
    sig = _signals()
    arrays = {k: v.numpy() for k, v in sig.items()}
    names = np.array(JOINTS)
    paths = {
        "savez": tmp_path / "plain.npz",
        "savez_compressed": tmp_path / "compressed.npz",
        "simulated": tmp_path / "simulated.npz",
        "write_log": tmp_path / "columns.npz",
    }
    np.savez(paths["savez"], joint_names=names, **arrays)
    np.savez_compressed(paths["savez_compressed"], joint_names=names, **arrays)
    _simulated(sig).save(paths["simulated"])
    write_log(JointLog(joint_names=JOINTS, **sig), paths["write_log"])
    return sig, paths


@pytest.mark.parametrize("kind", ["savez", "savez_compressed", "simulated", "write_log"])
def test_every_layout_reads_the_same_arrays(files, kind):
    sig, paths = files
    log = NpzLog(paths[kind])
    assert log.joint_names == JOINTS and set(log.members) == set(SIGNALS)
    assert all(log.shape(k) == (203, 3) for k in SIGNALS)
    with log.open() as read:  # ranges of 64 rows, in order, with a jump forward
        for k in SIGNALS:
            for a in (0, 64, 128, 192):
                assert np.array_equal(read(k, a, min(a + 64, 203)), sig[k][a : a + 64].numpy())
    back = read_log(paths[kind])
    assert back.joint_names == JOINTS and torch.equal(back.t, sig["t"])
    assert all(torch.equal(getattr(back, k), sig[k]) for k in SIGNALS)
    (src,) = log_sources(paths[kind], JOINTS[::-1])  # streamed, columns in the model's order
    assert src.perm == [2, 1, 0] and src.shape == (203, 3)
    (_, arrays), *_ = src.read([(10, 90, 0)])
    assert all(torch.equal(v, sig[k][10:90]) for k, v in zip(SIGNALS, arrays, strict=True))


def test_simulated_log_load_reads_through_the_archive(files):
    sig, paths = files
    back = SimulatedLog.load(paths["simulated"])
    assert isinstance(back, SimulatedLog) and back.source == str(paths["simulated"])
    assert all(torch.equal(getattr(back, k), sig[k]) for k in SIGNALS)
    assert torch.equal(back.tau_true, sig["tau"] + 1.0)
    with pytest.raises(ValueError, match="not a torchjfa SimulatedLog"):
        SimulatedLog.load(paths["savez"])


def test_archive_headers_and_members_loaded_whole(tmp_path):
    path = tmp_path / "f.npz"
    x = np.asfortranarray(np.arange(12.0).reshape(4, 3))
    np.savez(path, x=x, n=np.arange(5, dtype=np.int32))
    archive = NpzArchive(path)
    assert archive.members == ("x", "n")
    h = archive.headers(["x", "n"])
    assert h["x"].shape == (4, 3) and h["x"].fortran_order and h["n"].dtype == np.int32
    with archive.rows() as rows:  # Fortran order: the member is loaded whole, then sliced
        assert np.array_equal(rows("x", 1, 3), x[1:3])
        out = rows("n", 2, 5)
        assert out.dtype == np.float64 and np.array_equal(out, [2.0, 3.0, 4.0])


def test_archive_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such log file"):
        NpzArchive(tmp_path / "missing.npz")
    (tmp_path / "text.npz").write_text("t,q_a\n")
    with pytest.raises(LogError, match="is not an .npz file"):
        NpzArchive(tmp_path / "text.npz")
    path = tmp_path / "short.npz"
    np.savez(path, q=np.zeros((10, 2)))
    with NpzArchive(path).rows() as rows, pytest.raises(LogError, match="truncated"):
        rows("q", 5, 12)


def test_period_noise_lives_in_data_and_sim_re_exports_it():
    import torchjfa.data
    import torchjfa.sim

    assert torchjfa.sim.regressor_noise is torchjfa.data.regressor_noise
    assert torchjfa.sim.PeriodNoise is torchjfa.data.PeriodNoise


def test_data_does_not_import_sim():
    """Layering: `data` sits below `sim` (a fresh interpreter, so no other test's imports)."""
    import subprocess
    import sys

    code = (
        "import sys, torchjfa.data; print([m for m in sys.modules if m.startswith('torchjfa.sim')])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
