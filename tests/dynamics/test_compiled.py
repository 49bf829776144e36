"""The compiled regressor (generated C++, the default where a compiler is found) against the torch path."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
from dyn_robots import ROBOTS, mujoco_inverse, mujoco_model, random_state

import torchjfa.dynamics._kernel as kernel_module
from torchjfa.dynamics import RigidBodyModel

TOL = {torch.float64: 1e-12, torch.float32: 1e-4}


def _has_compiler() -> bool:
    try:
        kernel_module._compiler()
    except RuntimeError:
        return False
    return True


pytestmark = pytest.mark.skipif(not _has_compiler(), reason="no C++ compiler on PATH")


@pytest.fixture(autouse=True)
def _kernel_cache(tmp_path_factory, monkeypatch):
    # one cache per test session: each kernel is compiled once, nothing written to ~/.cache
    monkeypatch.setenv("TORCHJFA_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "kernels"))


def _model(name: str, **kw) -> RigidBodyModel:
    kind, source = ROBOTS[name]
    return (RigidBodyModel.from_urdf if kind == "urdf" else RigidBodyModel.from_mjcf)(source, **kw)


def _assert_close(actual, expected, dtype):
    tol = TOL[dtype]
    scale = float(expected.abs().max())
    torch.testing.assert_close(actual, expected, rtol=tol, atol=tol * scale)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("name", list(ROBOTS))
def test_compiled_equals_default(name, dtype):
    model = _model(name)
    # 37 samples: not a multiple of the 8 (16 in float32) samples of a block
    for batch in [(37,), (3, 4), (1,)]:
        q, qd, qdd = (v.to(dtype) for v in random_state(model.n_dof, batch, seed=len(batch)))
        expected = model.regressor(q, qd, qdd, compiled=False)
        Y = model.regressor(q, qd, qdd, compiled=True)
        assert Y.shape == expected.shape and Y.dtype == dtype and not Y.requires_grad
        _assert_close(Y, expected, dtype)
        # every zero of the default path is an exact zero here too (the kernel may have more:
        # folded constants give exact zeros where the default path leaves 1e-18 of rounding)
        assert bool((Y[expected == 0] == 0).all())


# slide joints with moving children (the robots above have slide joints only at the leaves)
SLIDE_MJCF = """<mujoco model="slides">
  <compiler angle="radian"/>
  <worldbody>
    <body name="carriage" pos="0.1 0 0.3" euler="0.2 0 0.4">
      <joint name="rail" type="slide" axis="1 0.3 0"/>
      <inertial pos="0.02 0.01 0" mass="2.0" fullinertia="0.02 0.03 0.025 0.001 0 0.002"/>
      <body name="arm" pos="0.2 0 0.1" quat="0.9238795 0 0.3826834 0">
        <joint name="pivot" type="hinge" axis="0 0.6 0.8" pos="0.02 0.01 0"/>
        <inertial pos="0.1 0 0.02" mass="1.0" fullinertia="0.01 0.012 0.006 0.0005 -0.0003 0.0002"/>
        <body name="slider" pos="0.3 0 0" euler="0.1 0.2 0.3">
          <joint name="extend" type="slide" axis="0 0 1"/>
          <inertial pos="0 0.02 0.05" mass="0.5" fullinertia="0.002 0.0025 0.0012 0 0.0001 0"/>
          <body name="tip" pos="0 0 0.1">
            <joint name="wrist" type="hinge" axis="1 0 0" pos="0 0 0.02"/>
            <inertial pos="0.01 0 0.03" mass="0.2" diaginertia="0.0004 0.0005 0.0003"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_slide_joints_with_children(tmp_path, dtype):
    path = tmp_path / "slides.xml"
    path.write_text(SLIDE_MJCF)
    model = RigidBodyModel.from_mjcf(str(path))
    assert model.joint_types == ("prismatic", "revolute", "prismatic", "revolute")
    q, qd, qdd = random_state(model.n_dof, (19,), seed=8)
    Y = model.regressor(q.to(dtype), qd.to(dtype), qdd.to(dtype), compiled=True)
    _assert_close(Y, model.regressor(q, qd, qdd, compiled=False).to(dtype), dtype)
    if dtype == torch.float64:
        expected = mujoco_inverse(
            mujoco_model("mjcf", str(path)), q.numpy(), qd.numpy(), qdd.numpy()
        )
        tau = (Y @ model.nominal_theta).numpy()
        np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def test_friction_columns_and_empty_batch():
    model = _model("small_urdf", friction=("viscous", "coulomb", "offset"))
    q, qd, qdd = random_state(model.n_dof, (21,), seed=3)
    qd[:5, 0] = 0.0  # sign(0) = 0
    expected = model.regressor(q, qd, qdd, compiled=False)
    Y = model.regressor(q, qd, qdd, compiled=True)
    _assert_close(Y, expected, torch.float64)
    for j in range(model.n_dof):
        assert torch.equal(Y[:, j, model.layout.index(j, "fc")], torch.sign(qd[:, j]))
        assert torch.equal(Y[:, j, model.layout.index(j, "fv")], qd[:, j])
        assert bool((Y[:, j, model.layout.index(j, "fo")] == 1).all())
    empty = model.regressor(q[:0], qd[:0], qdd[:0], compiled=True)
    assert empty.shape == (0, model.n_dof, model.n_params)


def test_threads_out_and_streaming():
    model = _model("branched_tree")
    q, qd, qdd = random_state(model.n_dof, (5003,), seed=4)  # 2 threads at 2048+ samples each
    expected = model.regressor(q, qd, qdd, compiled=False)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        Y = model.regressor(q, qd, qdd, compiled=True)
        out = torch.full_like(expected, float("nan"))
        result = model.regressor(q, qd, qdd, out=out, compiled=True)
    finally:
        torch.set_num_threads(threads)
    _assert_close(Y, expected, torch.float64)
    assert result.data_ptr() == out.data_ptr()
    torch.testing.assert_close(out, Y, rtol=0, atol=0)
    tau = expected @ model.nominal_theta
    chunks = list(model.regressor_chunks(q, qd, qdd, tau, chunk_size=999, compiled=True))
    rows = torch.cat([c[0] for c in chunks])
    _assert_close(rows, expected.reshape(-1, model.n_params), torch.float64)
    m = model.moments(q, qd, qdd, tau, compiled=True)
    ref = model.moments(q, qd, qdd, tau, compiled=False)
    _assert_close(m.xtx, ref.xtx, torch.float64)
    _assert_close(m.xty, ref.xty, torch.float64)


def test_grad_and_other_devices_take_the_default_path():
    model = _model("small_urdf")
    q, qd, qdd = random_state(model.n_dof, (4,), seed=5)
    qg = q.clone().requires_grad_(True)
    Y = model.regressor(qg, qd, qdd, compiled=True)
    assert Y.requires_grad  # the differentiable default path ran
    (g,) = torch.autograd.grad((Y @ model.nominal_theta).sum(), qg)
    assert torch.isfinite(g).all()
    _assert_close(Y.detach(), model.regressor(q, qd, qdd, compiled=True), torch.float64)
    assert torch.float64 in model._kernels  # the second call used the kernel
    Yh = model.regressor(q.half(), qd.half(), qdd.half(), compiled=True)  # no half kernel
    assert Yh.dtype == torch.float16 and torch.float16 not in model._kernels


def test_compile_regressor_cache_and_pickle():
    model = _model("small_urdf")
    seconds = model.compile_regressor(torch.float32)
    assert seconds > 0 and model.compile_regressor(torch.float32) == 0.0
    with pytest.raises(ValueError, match="float64 and float32"):
        model.compile_regressor(torch.float16)
    # a second model of the same robot loads the library from the disk cache
    other = _model("small_urdf")
    other.compile_regressor(torch.float32)
    assert other._kernels[torch.float32].from_cache
    kernel = pickle.loads(pickle.dumps(model._kernels[torch.float32]))
    q, qd, qdd = (v.float() for v in random_state(model.n_dof, (9,), seed=6))
    out = torch.empty(9, model.n_dof, model.n_params)
    kernel(out, q, qd, qdd)
    _assert_close(out, model.regressor(q, qd, qdd, compiled=False), torch.float32)


def test_no_compiler_raises(monkeypatch):
    monkeypatch.setattr(kernel_module.shutil, "which", lambda name: None)
    model = _model("small_urdf")
    q, qd, qdd = random_state(model.n_dof, (2,), seed=7)
    with pytest.raises(RuntimeError, match="C\\+\\+ compiler"):
        model.regressor(q, qd, qdd, compiled=True)


def test_default_is_the_kernel_and_a_fresh_build_says_so(tmp_path, monkeypatch, notes):
    monkeypatch.setenv("TORCHJFA_CACHE_DIR", str(tmp_path / "empty"))
    model = _model("small_urdf")
    q, qd, qdd = random_state(model.n_dof, (5,), seed=8)
    Y = model.regressor(q, qd, qdd)
    assert model._kernels[torch.float64] is not None  # compiled=None took the kernel
    assert not model._kernels[torch.float64].from_cache
    assert sum("compiling the regressor kernel" in r.getMessage() for r in notes.records) == 1
    _assert_close(Y, model.regressor(q, qd, qdd, compiled=False), torch.float64)
    # a second model of the same robot loads the kernel from the cache, without a note
    other = _model("small_urdf")
    other.regressor(q, qd, qdd)
    assert other._kernels[torch.float64].from_cache
    assert sum("compiling" in r.getMessage() for r in notes.records) == 1


def test_default_falls_back_to_the_torch_path_with_one_note(monkeypatch, notes):
    monkeypatch.setattr(kernel_module.shutil, "which", lambda name: None)
    model = _model("small_urdf")
    q, qd, qdd = random_state(model.n_dof, (3,), seed=9)
    threads = torch.get_num_threads()
    Y = model.regressor(q, qd, qdd)
    model.regressor(q, qd, qdd)
    _model("small_urdf").regressor(q, qd, qdd)
    fallbacks = [r for r in notes.records if "torch path runs" in r.getMessage()]
    assert len(fallbacks) == 1 and "C++ compiler" in fallbacks[0].getMessage()
    assert model._kernels[torch.float64] is None
    assert torch.get_num_threads() == threads  # the torch path restores the thread count
    monkeypatch.undo()  # the compiler is back: the forced path builds the kernel now
    _assert_close(Y, model.regressor(q, qd, qdd, compiled=True), torch.float64)


def test_torch_path_runs_on_one_thread_and_restores(monkeypatch):
    import torchjfa.dynamics._model as model_module

    seen = []
    fast = model_module.regressor_fast

    def spy(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return fast(*args, **kwargs)

    monkeypatch.setattr(model_module, "regressor_fast", spy)
    model = _model("small_urdf")
    q, qd, qdd = random_state(model.n_dof, (3,), seed=10)
    previous = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        model.regressor(q, qd, qdd, compiled=False)
        assert seen == [1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(previous)
