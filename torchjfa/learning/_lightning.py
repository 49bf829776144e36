"""`ResidualDynamicsModule`: a thin ``LightningModule`` that trains a `ResidualDynamics`, and
`load_checkpoint`, which rebuilds the trained model from a Lightning checkpoint in plain torch.

The residual network is injected (any ``nn.Module``; the default `MLP` otherwise) and left out of
the saved hyper-parameters; the identified model is given as a file of `torchjfa.io` (or, from
Python, as an `InverseDynamics`). The checkpoint gets, besides Lightning's ``state_dict`` and
``hyper_parameters``, an entry ``"torchjfa"`` with the identified model itself (description text,
layout, theta) so that `load_checkpoint` needs neither Lightning nor the original files.

The loss is the normalised mean squared torque error: per joint, the squared error divided by
that joint's torque variance in the training data, averaged over joints and samples (joints whose
torques differ by orders of magnitude count alike). It is also what ``val_loss`` reports.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence

import lightning as L
import torch
from torch import nn

from ..dynamics import InverseDynamics
from ..io import identified_from_dict, identified_to_dict, load_identified
from ._residual import MLP, JointResidual, ResidualDynamics

__all__ = ["ResidualDynamicsModule", "load_checkpoint", "CHECKPOINT_KEY"]

CHECKPOINT_KEY = "torchjfa"


def _build(hp: dict, identified: InverseDynamics | None, residual, features) -> ResidualDynamics:
    return ResidualDynamics(
        identified,
        residual,
        fine_tune=bool(hp["fine_tune"]),
        features=features,
        n_features=hp.get("n_features"),
        n_dof=None if identified is not None else hp["n_dof"],
        hidden=tuple(hp["hidden"]),
        seed=hp["seed"],
        residual_kind=hp.get("residual_kind", "mlp"),
    )


class ResidualDynamicsModule(L.LightningModule):
    """Trains ``tau = Y theta + r(features)`` (or, without an identified model, ``tau = r``).

    Args:
        residual: the residual network; default ``MLP(n_features, n_dof, hidden=hidden)``.
        identified: an identified-model file (`torchjfa.io.save_identified`), or from Python
            an `InverseDynamics`; None trains a purely learned model (give ``n_dof``).
        fine_tune: fine-tune theta through `VirtualParameters` (see `ResidualDynamics`).
        n_dof: joints, when there is no identified model.
        features: features of the residual (see `ResidualDynamics`; not saved as a
            hyper-parameter, give it again to `load_checkpoint`); n_features its width.
        residual_kind: the default residual, ``"mlp"`` or ``"joint"`` (see `ResidualDynamics`).
        hidden: of the default residual network.
        seed: of the default residual network.
        lr: Adam's learning rate.
        weight_decay: Adam's; parameters a module lists in its ``no_weight_decay()`` (the
            linear term of a `JointResidual`) are not decayed.
        scheduler: ``"cosine"`` (cosine annealing of the learning rate to 0 over
            ``trainer.max_epochs``) or ``"none"``.
        normalize: at the start of fitting, set the default MLP's input and output
            standardisation from the training data (the output from the residual targets
            ``tau - Y theta``).
    """

    def __init__(
        self,
        residual: nn.Module | None = None,
        *,
        identified: str | InverseDynamics | None = None,
        fine_tune: bool = False,
        n_dof: int | None = None,
        features: Callable[..., torch.Tensor] | None = None,
        n_features: int | None = None,
        residual_kind: str = "mlp",
        hidden: Sequence[int] = (64, 64),
        seed: int = 0,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        scheduler: str = "cosine",
        normalize: bool = True,
    ) -> None:
        super().__init__()
        ignore = ["residual", "features"]
        if isinstance(identified, os.PathLike):
            identified = os.fspath(identified)  # a plain string in the checkpoint
        if not (identified is None or isinstance(identified, str)):
            ignore.append("identified")
        self.save_hyperparameters(ignore=ignore)
        if scheduler not in ("cosine", "none"):
            raise ValueError(f"scheduler must be 'cosine' or 'none', got {scheduler!r}")
        if not lr > 0 or not weight_decay >= 0:
            raise ValueError(f"need lr > 0 and weight_decay >= 0, got {lr}, {weight_decay}")
        if isinstance(identified, str):
            identified = load_identified(identified)
        elif identified is not None and not isinstance(identified, InverseDynamics):
            raise TypeError(
                "identified must be a file path, an InverseDynamics or None, got "
                f"{type(identified)}"
            )
        hp = {
            "fine_tune": fine_tune,
            "n_features": n_features,
            "n_dof": n_dof,
            "hidden": hidden,
            "seed": seed,
            "residual_kind": residual_kind,
        }
        self.model = _build(hp, identified, residual, features)
        self._custom_residual = residual is not None
        self._custom_features = features is not None
        self.register_buffer("loss_weight", torch.ones(self.model.n_dof, dtype=torch.float64))
        self._fitted_statistics = False

    # ------------------------------------------------------------------ model
    def forward(self, q, qd, qdd, *, regressor=None) -> torch.Tensor:
        """`ResidualDynamics.forward`."""
        return self.model(q, qd, qdd, regressor=regressor)

    def _loss(self, batch) -> torch.Tensor:
        tau_hat = self.model(batch["q"], batch["qd"], batch["qdd"], regressor=batch.get("Y"))
        err = (tau_hat - batch["tau"]) ** 2 * self.loss_weight.to(tau_hat)
        return err.mean()

    # ------------------------------------------------------------------ hooks
    @torch.no_grad()
    def fit_statistics(self, tensors: dict[str, torch.Tensor]) -> None:
        """Set the loss weights (inverse per-joint torque variances) and, with ``normalize``,
        the default MLP's standardisation from training data; `setup` does it from the data
        module when this was not called.

        Args:
            tensors: ``{"q", "qd", "qdd", "tau"}`` ``(n, n_dof)`` and optionally ``"Y"``
                ``(n, n_dof, n_params)`` (see `SimulatedLogDataModule.train_tensors`).
        """
        tau = tensors["tau"]
        var = tau.var(0) if tau.shape[0] > 1 else torch.ones_like(tau[0])
        var = torch.where(var > 0, var, torch.ones_like(var))
        self.loss_weight.copy_(1.0 / var)
        residual = self.model.residual
        if self.hparams.normalize and isinstance(residual, MLP | JointResidual):
            q, qd, qdd = tensors["q"], tensors["qd"], tensors["qdd"]
            target = tau - self.model.rigid_body_torque(q, qd, qdd, regressor=tensors.get("Y"))
            residual.fit_normalization(self.model.features(q, qd, qdd), target)
        self._fitted_statistics = True

    def setup(self, stage: str) -> None:
        """Before fitting, set the loss weights (and the MLP's standardisation) from the
        training data of the trainer's data module, once (every process gets the same)."""
        if stage != "fit" or self._fitted_statistics:
            return
        dm = getattr(self.trainer, "datamodule", None)
        tensors = None
        if dm is not None and hasattr(dm, "train_tensors"):
            dm.setup("fit")
            tensors = dm.train_tensors()
        if tensors is not None:
            self.fit_statistics(tensors)

    def _logged_loss(self, batch, name: str) -> torch.Tensor:
        """The loss of a batch, logged as an epoch mean synchronised across processes."""
        loss = self._loss(batch)
        self.log(
            name,
            loss,
            on_step=False,
            on_epoch=True,
            sync_dist=True,
            batch_size=batch["q"].shape[0],
        )
        return loss

    def training_step(self, batch, batch_idx):
        return self._logged_loss(batch, "train_loss")

    def validation_step(self, batch, batch_idx):
        return self._logged_loss(batch, "val_loss")

    def test_step(self, batch, batch_idx):
        loss = self._loss(batch)
        self.log("test_loss", loss, sync_dist=True, batch_size=batch["q"].shape[0])
        return loss

    def configure_optimizers(self):
        exempt = {
            f"{prefix}.{name}" if prefix else name
            for prefix, module in self.named_modules()
            if hasattr(module, "no_weight_decay")
            for name in module.no_weight_decay()
        }
        params = [(n, p) for n, p in self.named_parameters() if p.requires_grad]
        groups = [
            {"params": [p for n, p in params if n not in exempt]},
            {"params": [p for n, p in params if n in exempt], "weight_decay": 0.0},
        ]
        opt = torch.optim.Adam(
            [g for g in groups if g["params"]],
            lr=self.hparams.lr,
            weight_decay=self.hparams.weight_decay,
        )
        epochs = getattr(self.trainer, "max_epochs", None) if self._trainer else None
        if self.hparams.scheduler == "none" or not epochs or epochs < 1:
            return opt
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        idyn = self.model.inverse_dynamics
        checkpoint[CHECKPOINT_KEY] = {
            "identified": None if idyn is None else identified_to_dict(idyn),
            "n_dof": self.model.n_dof,
            "n_features": self.model.n_features,
            "custom_residual": self._custom_residual,
            "custom_features": self._custom_features,
        }


def load_checkpoint(
    path: str | os.PathLike,
    *,
    residual: nn.Module | None = None,
    features: Callable[..., torch.Tensor] | None = None,
    map_location: str | torch.device = "cpu",
) -> ResidualDynamics:
    """Rebuild the `ResidualDynamics` of a `ResidualDynamicsModule` checkpoint, without Lightning.

    Reads the checkpoint with ``torch.load(weights_only=True)``, rebuilds the model from its
    hyper-parameters and the stored identified model, and loads the ``state_dict`` (strictly).

    Args:
        path: a Lightning ``.ckpt`` written while training a `ResidualDynamicsModule`.
        residual: an instance of the residual network's class, when it was not the default MLP
            (its weights are overwritten from the checkpoint).
        features: the features callable, when custom features were used.
        map_location: passed to ``torch.load``.

    Returns:
        The model in eval mode, giving the same predictions as the trained module.

    Raises:
        ValueError: if the file is not such a checkpoint, or a custom residual or features
            were used and not given.
    """
    ckpt = torch.load(os.fspath(path), map_location=map_location, weights_only=True)
    if CHECKPOINT_KEY not in ckpt or "state_dict" not in ckpt:
        raise ValueError(f"{os.fspath(path)!r} is not a ResidualDynamicsModule checkpoint")
    info = ckpt[CHECKPOINT_KEY]
    hp = dict(ckpt.get("hyper_parameters", {}))
    if info["custom_residual"] and residual is None:
        raise ValueError("the checkpoint's residual is not the default MLP: pass residual=")
    if info["custom_features"] and features is None:
        raise ValueError("the checkpoint used custom features: pass features=")
    idyn = None
    if info["identified"] is not None:
        idyn = identified_from_dict(info["identified"]).inverse_dynamics()
    hp.setdefault("hidden", (64, 64))
    hp.setdefault("seed", 0)
    hp.setdefault("fine_tune", False)
    hp["n_dof"] = info["n_dof"]
    hp["n_features"] = info["n_features"] if info["custom_features"] else None
    model = _build(hp, idyn, residual, features)
    prefix = "model."
    state = {k[len(prefix) :]: v for k, v in ckpt["state_dict"].items() if k.startswith(prefix)}
    model.load_state_dict(state, strict=True)
    return model.eval()
