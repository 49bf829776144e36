"""Shared pieces of the learning tests: a small simulated log and a quiet trainer."""

from __future__ import annotations

import contextlib
import warnings

import lightning as L

# what Lightning says on every small CPU run; nothing else is silenced
EXPECTED_WARNINGS = (
    r".*does not have many workers.*",
    r".*number of training batches.*is smaller than the logging interval.*",
    r".*Checkpoint directory .* exists and is not empty.*",
    r".*`isinstance\(treespec, LeafSpec\)` is deprecated.*",
)


@contextlib.contextmanager
def quiet_lightning():
    """Silence the expected Lightning warnings inside the block only."""
    with warnings.catch_warnings():
        for message in EXPECTED_WARNINGS:
            warnings.filterwarnings("ignore", message=message)
        yield


def trainer(root, **kwargs) -> L.Trainer:
    """A CPU trainer without logger, progress bar or model summary."""
    options = dict(
        accelerator="cpu",
        devices=1,
        max_epochs=2,
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=str(root),
        deterministic=True,
    )
    options.update(kwargs)
    return L.Trainer(**options)


def make_files(root, *, n_samples=640, seed=0):
    """A small head log (``log.npz``) and its nominal model with friction (``identified.npz``)."""
    import torch

    from torchjfa.dynamics import RigidBodyModel
    from torchjfa.io import save_identified
    from torchjfa.sim import generate_log, model_path, robot_effects

    log = generate_log("head", n_samples=n_samples, seed=seed)
    log.save(root / "log.npz")
    model = RigidBodyModel.from_mjcf(model_path("head"))
    theta = model.nominal_theta.clone()
    damping = torch.as_tensor(robot_effects("head")["damping"])
    theta.reshape(model.n_dof, -1)[:, 10] = damping  # head joints are in MuJoCo order
    save_identified(root / "identified.npz", model, theta)
    return root / "log.npz", root / "identified.npz", log, model, theta
