"""``torchjfa residual``, the LightningCLI entry point: a YAML config trains a model whose
checkpoint loads in torch."""

import importlib
import sys
from pathlib import Path

import pytest
import torch
import yaml

from torchjfa.cli import main as torchjfa
from torchjfa.cli._residual import main
from torchjfa.learning import (
    JointResidual,
    ResidualDynamicsModule,
    SimulatedLogDataModule,
    load_checkpoint,
)

from ._helpers import quiet_lightning

CONFIGS = Path(__file__).parents[2] / "torchjfa" / "learning" / "configs"


@pytest.fixture(autouse=True)
def _no_pytest_argv(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["torchjfa"])


def test_shipped_config_builds_the_model_and_data(head_files):
    log_path, id_path, *_ = head_files
    cfg = CONFIGS / "head_residual.yaml"
    args = ["--config", str(cfg), "--model.identified", str(id_path), "--data.path", str(log_path)]
    with quiet_lightning():
        cli = main(args, run=False)
    text = yaml.safe_load(cfg.read_text())
    assert cli.model.hparams.lr == text["model"]["lr"]
    assert cli.model.model.has_physics and not cli.model.model.fine_tune
    assert text["model"]["residual_kind"] == "joint"
    assert isinstance(cli.model.model.residual, JointResidual)
    assert cli.datamodule.batch_size == text["data"]["batch_size"]
    assert cli.trainer.max_epochs == text["trainer"]["max_epochs"]


def test_fit_from_a_yaml_config(head_files, tmp_path):
    log_path, id_path, log, *_ = head_files
    cfg = yaml.safe_load((CONFIGS / "head_residual.yaml").read_text())
    cfg["trainer"].update(max_epochs=2, default_root_dir=str(tmp_path), num_sanity_val_steps=0)
    cfg["model"].update(identified=str(id_path), hidden=[8])
    cfg["data"].update(path=str(log_path), chunk_size=64, batch_size=128)
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with quiet_lightning():
        cli = main(["fit", "--config", str(path)])
    assert isinstance(cli.model, ResidualDynamicsModule)
    assert isinstance(cli.datamodule, SimulatedLogDataModule)
    assert cli.datamodule.identified == str(id_path)  # linked from model.identified
    assert cli.trainer.current_epoch == 2
    ckpts = sorted(tmp_path.rglob("*.ckpt"))
    assert ckpts
    model = load_checkpoint(ckpts[-1])
    q, qd, qdd = log.q[:10], log.qd[:10], log.qdd[:10]
    with torch.no_grad():
        assert torch.equal(model(q, qd, qdd), cli.model.model(q, qd, qdd))


def test_the_torchjfa_command_runs_the_trainer(head_files, tmp_path):
    log_path, id_path, *_ = head_files
    cfg = yaml.safe_load((CONFIGS / "head_residual.yaml").read_text())
    cfg["trainer"].update(max_epochs=1, default_root_dir=str(tmp_path), num_sanity_val_steps=0,
                          limit_train_batches=2, limit_val_batches=1)  # fmt: skip
    cfg["model"].update(identified=str(id_path), hidden=[8])
    cfg["data"].update(path=str(log_path), chunk_size=64, batch_size=128)
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with quiet_lightning():
        assert torchjfa(["residual", "fit", "--config", str(path)]) == 0
    (ckpt,) = tmp_path.rglob("*.ckpt")
    model = load_checkpoint(ckpt)
    assert model.has_physics


def test_the_old_module_path_warns_and_is_the_same_code():
    sys.modules.pop("torchjfa.learning.cli", None)
    with pytest.warns(FutureWarning, match="torchjfa residual"):
        old = importlib.import_module("torchjfa.learning.cli")
    assert old.main is main


def test_bad_config_value_fails_to_parse(tmp_path):
    with quiet_lightning(), pytest.raises(SystemExit):
        main(["fit", "--model.lr", "fast", "--data.path", "x.npz"])
