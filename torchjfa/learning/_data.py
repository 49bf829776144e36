"""`SimulatedLogDataModule`: a Lightning data module over the library's joint-log files.

It reads a log file (a `torchjfa.sim.SimulatedLog` ``.npz``, or any log `torchjfa.data.read_log`
reads, with accelerations: a real log after `torchjfa.data.prepare` and `torchjfa.data.write_log`),
cuts it in time into a training part
(the first ``1 - val_fraction`` of the samples, rounded down to whole chunks) and a validation
part (the rest), so that no validation sample is ever seen in training and no shuffling mixes the
two; shuffling, when asked for, happens inside the training part only. Each item is one time
sample ``{"q", "qd", "qdd", "tau"}`` (``(n_dof,)`` each, float64), plus ``"Y"``
``(n_dof, n_params)``, the rigid-body regressor of the sample, when an identified model is
given: the regressor is the expensive part of the physics and is computed once, in chunks, in
`setup`. Use `log_tensors` for the same signals outside Lightning.
"""

from __future__ import annotations

import os

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset, DistributedSampler

from ..data import JointLog
from ..data._joints import permutation
from ..io import load_identified
from ..sim import load_log

__all__ = ["SimulatedLogDataModule", "StateTorqueDataset", "log_tensors", "time_split"]

_SIGNAL_SETS = {
    "measured": ("q", "qd", "qdd", "tau"),
    "true": ("q_true", "qd_true", "qdd_true", "tau_true"),
    "measured_inputs": ("q", "qd", "qdd", "tau_true"),
}


def log_tensors(log: JointLog, signals: str = "measured", joint_names=None):
    """``(q, qd, qdd, tau)`` of a log, each ``(n, n_dof)`` float64.

    Args:
        log: a `JointLog` with accelerations (a `torchjfa.sim.SimulatedLog`, or a real log
            after `torchjfa.data.prepare`); ``"true"`` and ``"measured_inputs"`` need a
            `SimulatedLog`'s ground truth.
        signals: ``"measured"`` (noisy q, qd, tau and the differentiated qdd, what a robot
            gives), ``"true"`` (the noiseless state and applied torque) or
            ``"measured_inputs"`` (measured state, true torque: for evaluation).
        joint_names: reorder the columns to these joint names (e.g. a model's
            ``joint_names``); default the log's order.
    """
    if signals not in _SIGNAL_SETS:
        raise ValueError(f"signals must be one of {sorted(_SIGNAL_SETS)}, got {signals!r}")
    where = getattr(log, "source", "the log")
    if log.qd is None or log.qdd is None:
        raise ValueError(
            f"{where} has no {'velocities' if log.qd is None else 'accelerations'}; prepare it "
            "first (torchjfa.data.prepare differentiates the positions)"
        )
    missing = [k for k in _SIGNAL_SETS[signals] if getattr(log, k, None) is None]
    if missing:
        raise ValueError(
            f"signals={signals!r} needs {missing}, the ground truth of a simulated log; "
            f"{where} is a {type(log).__name__} without it (use signals='measured')"
        )
    out = [getattr(log, k) for k in _SIGNAL_SETS[signals]]
    if joint_names is not None:
        perm = permutation(log.joint_names, joint_names, where=where, want_name="the model")
        out = [v[:, perm] for v in out]
    return tuple(out)


def time_split(n: int, *, val_fraction: float, chunk_size: int) -> tuple[slice, slice]:
    """Training and validation slices of ``n`` time samples, split at a chunk boundary.

    Training is the first ``floor((1 - val_fraction) n / chunk_size)`` whole chunks (at least
    one), validation the rest (empty when ``val_fraction == 0``).
    """
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive int, got {chunk_size!r}")
    if val_fraction == 0.0:
        return slice(0, n), slice(n, n)
    n_train = max(1, int((1.0 - val_fraction) * n) // chunk_size) * chunk_size
    if n_train >= n:
        raise ValueError(
            f"a log of {n} samples is too short for chunks of {chunk_size} and val_fraction "
            f"{val_fraction}"
        )
    return slice(0, n_train), slice(n_train, n)


class StateTorqueDataset(Dataset):
    """Time samples ``{"q", "qd", "qdd", "tau"[, "Y"]}`` of ``(n, n_dof)`` tensors."""

    def __init__(self, q, qd, qdd, tau, regressor=None) -> None:
        self.tensors = {"q": q, "qd": qd, "qdd": qdd, "tau": tau}
        if regressor is not None:
            self.tensors["Y"] = regressor
        n = q.shape[0]
        for k, v in self.tensors.items():
            if v.shape[0] != n:
                raise ValueError(f"{k} has {v.shape[0]} samples, q has {n}")

    def __len__(self) -> int:
        return self.tensors["q"].shape[0]

    def __getitem__(self, i):
        return {k: v[i] for k, v in self.tensors.items()}


class SimulatedLogDataModule(L.LightningDataModule):
    """Train/validation data from a log file, split by time.

    Args:
        path: the log: a `torchjfa.sim.SimulatedLog` ``.npz`` (`SimulatedLog.save`), or a
            CSV, NPZ or Parquet log with ``qdd`` columns (`torchjfa.data.write_log` of a
            prepared `JointLog`), read by `torchjfa.sim.load_log`.
        identified: optionally an identified-model file (`torchjfa.io.save_identified`); each
            sample then carries its regressor ``"Y"`` and the columns follow the model's joint
            order. Memory: ``8 n n_dof n_params`` bytes.
        signals: which signals to train on (see `log_tensors`); default the measured ones.
        val_fraction: fraction of the log, at its end, held out for validation.
        chunk_size: the split falls on a multiple of this many samples; the regressor is
            computed this many samples at a time.
        n_train: use only the first ``n_train`` training samples (data-efficiency studies);
            None: all.
        batch_size: samples per batch (per process under DDP).
        shuffle: shuffle the training samples (within the training part) every epoch.
        seed: seeds the shuffling.
        num_workers: data-loader workers.
    """

    def __init__(
        self,
        path: str,
        *,
        identified: str | None = None,
        signals: str = "measured",
        val_fraction: float = 0.2,
        chunk_size: int = 1024,
        n_train: int | None = None,
        batch_size: int = 256,
        shuffle: bool = True,
        seed: int = 0,
        num_workers: int = 0,
    ) -> None:
        super().__init__()
        if signals not in _SIGNAL_SETS:
            raise ValueError(f"signals must be one of {sorted(_SIGNAL_SETS)}, got {signals!r}")
        if not 0.0 <= val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
        for name, v in (("chunk_size", chunk_size), ("batch_size", batch_size)):
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive int, got {v!r}")
        if n_train is not None and (isinstance(n_train, bool) or n_train < 1):
            raise ValueError(f"n_train must be a positive int or None, got {n_train!r}")
        path = os.fspath(path)  # plain strings in the checkpoint's hyper-parameters
        identified = None if identified is None else os.fspath(identified)
        self.save_hyperparameters()
        self.path = path
        self.identified = identified
        self.signals = signals
        self.val_fraction = val_fraction
        self.chunk_size = chunk_size
        self.n_train = n_train
        self.batch_size = batch_size
        self.shuffle = shuffle
        self.seed = seed
        self.num_workers = num_workers
        self.train_set: StateTorqueDataset | None = None
        self.val_set: StateTorqueDataset | None = None

    def _regressor(self, model, q, qd, qdd) -> torch.Tensor:
        return torch.cat(
            [
                model.regressor(
                    q[s : s + self.chunk_size],
                    qd[s : s + self.chunk_size],
                    qdd[s : s + self.chunk_size],
                    chunk_size=self.chunk_size,
                )
                for s in range(0, q.shape[0], self.chunk_size)
            ]
        )

    def setup(self, stage: str | None = None) -> None:
        """Read the log, split it by time and (with ``identified``) compute the regressors."""
        if self.train_set is not None:
            return
        log = load_log(self.path)
        model = None if self.identified is None else load_identified(self.identified).model
        names = None if model is None else model.joint_names
        signals = log_tensors(log, self.signals, names)
        train, val = time_split(
            log.n_samples, val_fraction=self.val_fraction, chunk_size=self.chunk_size
        )
        if self.n_train is not None:
            if self.n_train > train.stop:
                raise ValueError(
                    f"n_train={self.n_train} but the training part has {train.stop} samples"
                )
            train = slice(0, self.n_train)
        sets = []
        for part in (train, val):
            q, qd, qdd, tau = (v[part].contiguous() for v in signals)
            Y = None if model is None or q.shape[0] == 0 else self._regressor(model, q, qd, qdd)
            sets.append(StateTorqueDataset(q, qd, qdd, tau, Y))
        self.train_set, self.val_set = sets

    def _world(self) -> tuple[int, int]:
        trainer = getattr(self, "trainer", None)
        if trainer is None:
            return 1, 0
        return int(trainer.world_size), int(trainer.global_rank)

    def train_dataloader(self) -> DataLoader:
        """Batches of the training part. Under several processes each gets every
        ``world_size``-th sample (a `DistributedSampler` made here, so that without shuffling
        the processes' batches together are exactly one process's batch of
        ``world_size * batch_size``)."""
        world, rank = self._world()
        if world > 1:
            sampler = DistributedSampler(
                self.train_set,
                num_replicas=world,
                rank=rank,
                shuffle=self.shuffle,
                seed=self.seed,
            )
            return DataLoader(
                self.train_set,
                batch_size=self.batch_size,
                sampler=sampler,
                num_workers=self.num_workers,
            )
        return DataLoader(
            self.train_set,
            batch_size=self.batch_size,
            shuffle=self.shuffle,
            num_workers=self.num_workers,
            generator=torch.Generator().manual_seed(self.seed) if self.shuffle else None,
        )

    def val_dataloader(self) -> DataLoader:
        if self.val_set is None or len(self.val_set) == 0:
            return []
        return DataLoader(
            self.val_set, batch_size=self.batch_size, shuffle=False, num_workers=self.num_workers
        )

    def train_tensors(self) -> dict[str, torch.Tensor]:
        """The training part's ``(n, ...)`` tensors (after `setup`)."""
        if self.train_set is None:
            raise RuntimeError("call setup() first")
        return self.train_set.tensors
