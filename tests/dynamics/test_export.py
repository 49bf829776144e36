"""`InverseDynamics` through `torch.export` (saved and loaded) and `torch.compile`: the traced
graphs give the eager outputs, and tracing leaves the eager model as it was.

Eager CPU calls use the compiled C++ regressor where a compiler exists, the traced graphs the
torch path; the two agree to about 1e-15 relative in float64 (tests/dynamics/test_compiled.py),
so 1e-12 of the largest torque leaves a wide margin."""

from __future__ import annotations

import shutil

import pytest
import torch
from torch import nn
from torch.export import Dim

from torchjfa.dynamics import InverseDynamics, RigidBodyModel
from torchjfa.sim import model_path

RTOL = 1e-12


@pytest.fixture(scope="module")
def head():
    # smooth Coulomb columns: the traced path overwrites them as the eager one does
    return RigidBodyModel.from_mjcf(
        model_path("head"), friction=("viscous", "coulomb"), coulomb_velocity=0.05
    )


def _theta(model: RigidBodyModel) -> torch.Tensor:
    theta = model.nominal_theta
    for j in model.joint_names:
        theta[model.layout.index(j, "fv")] = 0.1
        theta[model.layout.index(j, "fc")] = 0.02
    return theta


def _states(n_dof: int, batch: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    return tuple(torch.randn(batch, n_dof, dtype=torch.float64, generator=g) for _ in range(3))


def _assert_same(actual: torch.Tensor, expected: torch.Tensor) -> None:
    actual, expected = actual.detach(), expected.detach()
    assert actual.shape == expected.shape and actual.dtype == expected.dtype
    atol = RTOL * float(expected.abs().max())
    torch.testing.assert_close(actual, expected, rtol=0, atol=atol)


def test_exported_program_saved_and_loaded_gives_the_eager_torques(head, tmp_path):
    idyn = InverseDynamics(head, _theta(head))
    batch = Dim("batch")
    program = torch.export.export(
        idyn, _states(head.n_dof, 5, seed=0), dynamic_shapes=({0: batch}, {0: batch}, {0: batch})
    )
    torch.export.save(program, tmp_path / "head.pt2")
    loaded = torch.export.load(tmp_path / "head.pt2").module()
    for n in (9, 1):  # other batch sizes than the example's
        q, qd, qdd = _states(head.n_dof, n, seed=n)
        _assert_same(loaded(q, qd, qdd), idyn(q, qd, qdd))


def test_export_gives_a_program_for_any_batch_size(head, tmp_path):
    """`InverseDynamics.export`: traced once at its example's batch, it runs at any other,
    batch 1 included, and survives a save and load."""
    idyn = InverseDynamics(head, _theta(head))
    program = idyn.export()
    torch.export.save(program, tmp_path / "head.pt2")
    loaded = torch.export.load(tmp_path / "head.pt2").module()
    for n in (1, 7, 300):
        q, qd, qdd = _states(head.n_dof, n, seed=10 + n)
        _assert_same(loaded(q, qd, qdd), idyn(q, qd, qdd))
    with pytest.raises(ValueError, match="batch must be an int >= 2"):
        idyn.export(batch=1)


def test_exporting_leaves_the_eager_model_as_it_was(head):
    model = RigidBodyModel.from_mjcf(model_path("head"))  # fresh: no cached constants yet
    idyn = InverseDynamics(model)
    torch.export.export(idyn, _states(model.n_dof, 3, seed=1))
    # the autograd path builds (and caches) its constants now, from real numbers
    q, qd, qdd = _states(model.n_dof, 3, seed=2)
    qg = q.clone().requires_grad_(True)
    _assert_same(idyn(qg, qd, qdd), idyn(q, qd, qdd))
    with pytest.raises(ValueError, match="NaN"):  # eager calls still check their inputs
        idyn(torch.full_like(q, float("nan")), qd, qdd)


def test_exported_forward_dynamics_and_consistent_theta(head):
    idyn = InverseDynamics(head, _theta(head), trainable=True)

    class Accelerations(nn.Module):
        def __init__(self, dynamics):
            super().__init__()
            self.dynamics = dynamics

        def forward(self, q, qd, tau):
            return self.dynamics.forward_dynamics(q, qd, tau)

    q, qd, tau = _states(head.n_dof, 4, seed=3)
    program = torch.export.export(Accelerations(idyn), (q, qd, tau))
    # qdd = M^-1 (tau - h): the regressors' 1e-15 relative differences grow by cond(M) ~ 1e3
    expected = idyn.forward_dynamics(q, qd, tau).detach()
    atol = 1e3 * RTOL * float(expected.abs().max())
    actual = program.module()(q, qd, tau).detach()
    torch.testing.assert_close(actual, expected, rtol=0, atol=atol)
    program = torch.export.export(idyn, (q, qd, tau))
    _assert_same(program.module()(q, qd, tau), idyn(q, qd, tau))


_CXX = shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")


@pytest.mark.skipif(_CXX is None, reason="torch.compile's CPU backend needs a C++ compiler")
# torch's own compiler stack warns about its internal deprecations; not ours to fix
@pytest.mark.filterwarnings("ignore::DeprecationWarning:torch.*")
@pytest.mark.filterwarnings("ignore::FutureWarning:torch.*")
def test_compiled_module_gives_the_eager_torques_in_one_graph(head):
    idyn = InverseDynamics(head, _theta(head))
    compiled = torch.compile(idyn, fullgraph=True)  # fullgraph: a graph break raises
    q, qd, qdd = _states(head.n_dof, 6, seed=4)
    _assert_same(compiled(q, qd, qdd), idyn(q, qd, qdd))


def test_a_residual_on_the_identified_model_exports(head):
    """`ResidualDynamics` (the frozen model plus a network) traces through the same torch path:
    the exported program gives the eager torques."""
    from torchjfa.learning import ResidualDynamics

    torch.manual_seed(0)
    model = ResidualDynamics(InverseDynamics(head, _theta(head))).double()
    with torch.no_grad():  # a residual that is not zero, so that the network is in the graph
        for p in model.residual.parameters():
            p.normal_(0.0, 0.1)
    states = _states(head.n_dof, 6, seed=3)
    program = torch.export.export(model, states)
    _assert_same(program.module()(*states), model(*states))
