"""Saving and loading identified models: bitwise round trips, in this and in a fresh process."""

import io
import shutil
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest
import torch

import torchjfa
import torchjfa.robots
from torchjfa.dynamics import InverseDynamics, RigidBodyModel
from torchjfa.io import (
    identified_from_dict,
    identified_to_dict,
    load_identified,
    read_identified,
    save_identified,
)
from torchjfa.sim import model_path


def _perturbed_theta(model, seed=0):
    g = torch.Generator().manual_seed(seed)
    theta = model.nominal_theta
    return theta * (1 + 0.1 * torch.rand(theta.shape, generator=g, dtype=torch.float64))


def _states(n_dof, n=32, seed=1):
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(n, n_dof, generator=g, dtype=torch.float64) for _ in range(3)]


@pytest.fixture(scope="module")
def head():
    return RigidBodyModel.from_mjcf(model_path("head"))


@pytest.fixture(scope="module")
def panda():
    return RigidBodyModel.from_urdf(
        torchjfa.robots.path("panda"), friction=("viscous", "coulomb"), gravity=(0.0, 0.0, -9.8)
    )


@pytest.mark.parametrize("which", ["head", "panda"])
def test_round_trip_gives_bitwise_identical_torques(which, head, panda, tmp_path):
    model = head if which == "head" else panda
    theta = _perturbed_theta(model)
    path = tmp_path / "identified.npz"
    save_identified(
        path,
        model,
        theta,
        output_noise=0.25,
        input_noise=torch.ones(model.n_params),
        estimator="BayesianJFA",
    )
    idyn = load_identified(path)
    assert isinstance(idyn, InverseDynamics)
    assert not idyn.trainable
    q, qd, qdd = _states(model.n_dof)
    expected = InverseDynamics(model, theta)(q, qd, qdd)
    assert torch.equal(idyn(q, qd, qdd), expected)
    assert torch.equal(idyn.theta.detach(), theta)
    assert idyn.model.parameter_names == model.parameter_names
    assert idyn.model.friction == model.friction
    assert torch.equal(idyn.model.gravity, model.gravity)
    record = read_identified(path)
    assert record.library_version == torchjfa.__version__
    assert record.extras["estimator"] == "BayesianJFA"
    assert float(record.extras["output_noise"]) == 0.25
    assert torch.equal(record.extras["input_noise"], torch.ones(model.n_params))
    assert record.source_path == model.source_path


def test_inverse_dynamics_is_saved_with_its_theta_and_loads_trainable(head, tmp_path):
    theta = _perturbed_theta(head, seed=3)
    path = tmp_path / "idyn.npz"
    save_identified(path, InverseDynamics(head, theta))
    idyn = load_identified(path, trainable="unconstrained")
    assert idyn.trainable
    assert torch.equal(idyn.theta.detach(), theta)


def test_loads_from_the_stored_text_when_the_description_file_is_gone(tmp_path):
    src = tmp_path / "robot.xml"
    shutil.copy(torchjfa.robots.path("branched_tree"), src)
    model = RigidBodyModel.from_mjcf(src)
    theta = _perturbed_theta(model)
    save_identified(tmp_path / "m.npz", model, theta)
    src.unlink()
    idyn = load_identified(tmp_path / "m.npz")
    q, qd, qdd = _states(model.n_dof)
    assert torch.equal(idyn(q, qd, qdd), model.inverse_dynamics(q, qd, qdd, theta))
    assert idyn.model.source_path is None  # rebuilt from the XML text


def test_a_fresh_process_loads_the_file_and_gives_the_same_torques(head, tmp_path):
    theta = _perturbed_theta(head, seed=5)
    save_identified(tmp_path / "m.npz", head, theta)
    q, qd, qdd = _states(head.n_dof, n=16, seed=7)
    np.savez(tmp_path / "states.npz", q=q.numpy(), qd=qd.numpy(), qdd=qdd.numpy())
    code = textwrap.dedent(
        """
        import sys
        import numpy as np
        import torch
        from torchjfa.io import load_identified
        idyn = load_identified(sys.argv[1])
        s = np.load(sys.argv[2])
        tau = idyn(*(torch.from_numpy(s[k]) for k in ("q", "qd", "qdd")))
        np.save(sys.argv[3], tau.detach().numpy())
        """
    )
    out = tmp_path / "tau.npy"
    subprocess.run(
        [
            sys.executable,
            "-c",
            code,
            str(tmp_path / "m.npz"),
            str(tmp_path / "states.npz"),
            str(out),
        ],
        check=True,
        timeout=120,
    )
    expected = head.inverse_dynamics(q, qd, qdd, theta).numpy()
    assert np.array_equal(np.load(out), expected)


def test_dict_form_survives_torch_save_with_weights_only(head, tmp_path):
    theta = _perturbed_theta(head)
    torch.save(identified_to_dict(head, theta, output_noise=torch.tensor(0.5)), tmp_path / "d.pt")
    record = identified_from_dict(torch.load(tmp_path / "d.pt", weights_only=True))
    assert torch.equal(record.theta, theta)
    assert float(record.extras["output_noise"]) == 0.5
    q, qd, qdd = _states(head.n_dof)
    assert torch.equal(
        record.inverse_dynamics()(q, qd, qdd), head.inverse_dynamics(q, qd, qdd, theta)
    )


def test_bad_input_is_rejected(head, tmp_path):
    with pytest.raises(ValueError, match="shape"):
        save_identified(tmp_path / "a.npz", head, torch.zeros(3))
    with pytest.raises(ValueError, match="theta is required"):
        save_identified(tmp_path / "a.npz", head)
    with pytest.raises(TypeError, match="RigidBodyModel"):
        save_identified(tmp_path / "a.npz", "head", torch.zeros(77))
    with pytest.raises(TypeError, match="extra"):
        save_identified(tmp_path / "a.npz", head, head.nominal_theta, bad={"a": 1})
    with pytest.raises(ValueError, match="NaN"):
        save_identified(tmp_path / "a.npz", head, torch.full((77,), float("nan")))
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not a torchjfa model file"):
        load_identified(tmp_path / "other.npz")
    with pytest.raises(ValueError, match="format"):
        identified_from_dict({"theta": torch.zeros(3)})


def _member_data(blob: bytes, name: str) -> tuple[int, int]:
    """``(start, size)`` of a zip member's compressed bytes (after its local header)."""
    info = zipfile.ZipFile(io.BytesIO(blob)).getinfo(name)
    off = info.header_offset
    n_name = int.from_bytes(blob[off + 26 : off + 28], "little")
    n_extra = int.from_bytes(blob[off + 28 : off + 30], "little")
    return off + 30 + n_name + n_extra, info.compress_size


def corrupted(blob: bytes, kind: str) -> list[bytes]:
    """Damaged or foreign versions of a valid model file's bytes ``blob``."""
    if kind == "truncated":  # cut at several places: in the data, the directory, the end record
        return [blob[:k] for k in (len(blob) // 3, len(blob) // 2, len(blob) - 30, len(blob) - 1)]
    if kind == "bit-flipped":  # every bit of three bytes inside theta's deflate stream
        # (CRC-32 detects any single-bit error in the data; the stream's first bit, BFINAL, and
        # its last two bytes' padding bits may flip without changing the data, so not those)
        start, size = _member_data(blob, "theta.npy")
        out = []
        for pos in (start + 1, start + size // 2, start + size - 3):
            for bit in range(8):
                b = bytearray(blob)
                b[pos] ^= 1 << bit
                out.append(bytes(b))
        return out
    if kind == "empty":
        return [b""]
    if kind == "foreign":  # another program's .npz, a .npy, a CSV, a zip of something else
        npz, npy, other = io.BytesIO(), io.BytesIO(), io.BytesIO()
        np.savez(npz, theta=np.zeros(77), x=np.arange(3))
        np.save(npy, np.zeros(77))
        with zipfile.ZipFile(other, "w") as z:
            z.writestr("readme.txt", "not numpy")
        partial = io.BytesIO()  # the format entry without the rest (a file cut by hand)
        np.savez(partial, format=np.array("torchjfa.IdentifiedModel"), version=np.array(1))
        csv = b"t,q_a,tau_a\n0,0,0\n"
        return [npz.getvalue(), npy.getvalue(), other.getvalue(), partial.getvalue(), csv]
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["truncated", "bit-flipped", "empty", "foreign"])
def test_a_damaged_or_foreign_file_raises_one_clear_value_error(kind, head, tmp_path):
    path = tmp_path / "model.npz"
    save_identified(path, head, _perturbed_theta(head))
    blob = path.read_bytes()
    load_identified(path)  # the intact file loads
    for i, bad in enumerate(corrupted(blob, kind)):
        assert bad != blob
        p = tmp_path / f"bad{i}.npz"
        p.write_bytes(bad)
        with pytest.raises(ValueError) as info:
            load_identified(p)
        msg = str(info.value)
        assert type(info.value) is ValueError, type(info.value)
        assert "\n" not in msg
        assert repr(str(p)) in msg and "not a torchjfa model file, or it is damaged" in msg
        assert "write it again" in msg
        with pytest.raises(ValueError, match="not a torchjfa model file"):
            read_identified(p)


def test_a_missing_file_stays_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.npz"):
        load_identified(tmp_path / "nowhere.npz")


def test_a_stored_theta_of_the_wrong_shape_is_refused(head):
    data = identified_to_dict(head, _perturbed_theta(head))
    data["theta"] = data["theta"][:-1]
    with pytest.raises(ValueError, match=r"shape \(76,\).*needs \(77,\)"):
        identified_from_dict(data)
    del data["theta"]
    with pytest.raises(ValueError, match=r"\['theta'\] missing"):
        identified_from_dict(data)


def test_the_cutoff_the_model_was_identified_at_is_read_back(head, tmp_path):
    """``cutoff_hz`` is the stored extra; a file without one (or with text there) gives the
    library's default, which is what `evaluate` and the payload prepare logs at."""
    from torchjfa.data import DEFAULT_CUTOFF_HZ

    theta = _perturbed_theta(head)
    save_identified(tmp_path / "a.npz", head, theta, cutoff_hz=7.5)
    save_identified(tmp_path / "b.npz", head, theta)
    save_identified(tmp_path / "c.npz", head, theta, cutoff_hz="auto")
    assert read_identified(tmp_path / "a.npz").cutoff_hz == 7.5
    assert read_identified(tmp_path / "b.npz").cutoff_hz == DEFAULT_CUTOFF_HZ
    assert read_identified(tmp_path / "c.npz").cutoff_hz == DEFAULT_CUTOFF_HZ
    assert DEFAULT_CUTOFF_HZ != 7.5


def test_the_module_imports_nothing_above_it():
    """io sits below identification and is imported by the package: it imports neither, and
    the version it writes is the installed distribution's."""
    import ast
    import importlib.metadata
    from pathlib import Path

    import torchjfa.io

    tree = ast.parse(Path(torchjfa.io.__file__).read_text())
    imported = [
        (node.level, node.module or "")
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
    ]
    assert (1, "") not in imported  # no `from . import ...`: the package itself
    assert not [m for level, m in imported if m.split(".")[0] in ("identification", "torchjfa")]
    assert torchjfa.io._library_version() == importlib.metadata.version("torchjfa")
