"""`ResidualDynamicsModule`: training on one and on two processes (DDP, gloo), checkpoints that
load back into plain torch."""

import pytest
import torch
from torch import nn

from torchjfa.io import load_identified
from torchjfa.learning import (
    ResidualDynamicsModule,
    SimulatedLogDataModule,
    load_checkpoint,
    nmse,
)

from ._helpers import quiet_lightning, trainer


def _data(head_files, **kw):
    log_path, id_path, *_ = head_files
    options = dict(
        identified=id_path, val_fraction=0.2, chunk_size=64, batch_size=64, shuffle=False
    )
    options.update(kw)
    return SimulatedLogDataModule(log_path, **options)


def _flat(module):
    return torch.cat([p.detach().flatten() for p in module.parameters()])


@pytest.mark.parametrize("variant", ["frozen", "fine_tune", "learned_only", "joint"])
def test_fit_lowers_the_loss_and_the_checkpoint_loads_without_lightning(
    head_files, tmp_path, variant
):
    _, id_path, log, model, theta = head_files
    kw = {
        "learned_only": dict(n_dof=7),
        "fine_tune": dict(identified=str(id_path), fine_tune=True),
        "frozen": dict(identified=str(id_path)),
        "joint": dict(identified=str(id_path), residual_kind="joint", weight_decay=1e-2),
    }[variant]
    module = ResidualDynamicsModule(hidden=(16,), lr=1e-2, **kw)
    dm = _data(head_files, signals="true")  # noiseless: the residual is the unmodeled effects
    dm.setup("fit")
    val = dm.val_set.tensors
    with quiet_lightning():
        tr = trainer(tmp_path, max_epochs=8, num_sanity_val_steps=0)
        tr.fit(module, dm)
    # the loss weights are the inverse training torque variances
    torch.testing.assert_close(module.loss_weight, 1 / dm.train_tensors()["tau"].var(0))
    with torch.no_grad():
        pred = module.model(val["q"], val["qd"], val["qdd"])
    expected = (((pred - val["tau"]) ** 2) * module.loss_weight).mean()
    torch.testing.assert_close(tr.callback_metrics["val_loss"].double(), expected)
    if variant == "joint":  # the physical linear term is not decayed, the networks are
        groups = tr.optimizers[0].param_groups
        linear = module.model.residual.linear
        assert [g["weight_decay"] for g in groups] == [1e-2, 0.0]
        assert [p is linear for p in groups[1]["params"]] == [True]
    if variant in ("frozen", "joint"):  # training improves on the identified model alone
        idyn = load_identified(id_path)
        with torch.no_grad():
            base = idyn(val["q"], val["qd"], val["qdd"])
        assert nmse(pred, val["tau"]) < nmse(base, val["tau"])
    if variant == "fine_tune":
        assert not torch.equal(module.model.theta().detach(), theta)
    ckpt = tr.checkpoint_callback.best_model_path
    raw = torch.load(ckpt, weights_only=True)
    assert "residual" not in raw["hyper_parameters"]
    assert raw["hyper_parameters"]["hidden"] == (16,)
    rebuilt = load_checkpoint(ckpt)
    assert type(rebuilt).__name__ == "ResidualDynamics"
    with torch.no_grad():
        again = rebuilt(val["q"], val["qd"], val["qdd"])
    assert torch.equal(again, pred)
    assert rebuilt.fine_tune == (variant == "fine_tune")
    assert rebuilt.has_physics == (variant != "learned_only")


def test_injected_residual_is_not_a_hyperparameter_and_is_given_back_to_the_loader(
    head_files, tmp_path
):
    _, id_path, log, *_ = head_files

    def net():
        torch.manual_seed(0)
        return nn.Sequential(nn.Linear(21, 8), nn.Tanh(), nn.Linear(8, 7)).double()

    module = ResidualDynamicsModule(net(), identified=str(id_path), lr=1e-3)
    with quiet_lightning():
        tr = trainer(tmp_path, max_epochs=1, num_sanity_val_steps=0)
        tr.fit(module, _data(head_files))
    ckpt = tr.checkpoint_callback.best_model_path
    with pytest.raises(ValueError, match="residual="):
        load_checkpoint(ckpt)
    rebuilt = load_checkpoint(ckpt, residual=net())
    q, qd, qdd = log.q[:20], log.qd[:20], log.qdd[:20]
    with torch.no_grad():
        assert torch.equal(rebuilt(q, qd, qdd), module.model(q, qd, qdd))


@pytest.mark.parametrize(
    "strategy", ["ddp_fork", pytest.param("ddp_spawn", marks=pytest.mark.slow)]
)
def test_two_processes_give_the_one_process_result(head_files, tmp_path, strategy):
    """Same effective batch (2 x 32 vs 1 x 64), no shuffling, seeded initialisation."""
    _, id_path, *_ = head_files
    results = {}
    for devices, batch, strat in ((1, 64, "auto"), (2, 32, strategy)):
        module = ResidualDynamicsModule(identified=str(id_path), hidden=(16,), lr=3e-3)
        initial = _flat(module)
        with quiet_lightning():
            tr = trainer(
                tmp_path / strat,
                devices=devices,
                strategy=strat,
                max_epochs=2,
                enable_checkpointing=False,
                num_sanity_val_steps=0,
            )
            tr.fit(module, _data(head_files, batch_size=batch))
        results[devices] = _flat(module)
        assert not torch.allclose(results[devices], initial)  # it did train
    torch.testing.assert_close(results[2], results[1], rtol=1e-9, atol=1e-12)


def test_bad_arguments_are_rejected(head_files):
    with pytest.raises(ValueError, match="scheduler"):
        ResidualDynamicsModule(n_dof=2, scheduler="step")
    with pytest.raises(ValueError, match="lr"):
        ResidualDynamicsModule(n_dof=2, lr=0.0)
    with pytest.raises(TypeError, match="identified"):
        ResidualDynamicsModule(identified=3)
