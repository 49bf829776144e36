"""Identified rigid-body dynamics composed with learned residual dynamics, trained with Lightning.

- `ResidualDynamics`: ``tau = Y(q, qd, qdd) theta + r(features)`` as a plain ``nn.Module``, the
  identified theta frozen or fine-tuned through `VirtualParameters`; the residual network is an
  `MLP` of the whole state or a `JointResidual` (each joint from its own state).
- `ResidualDynamicsModule` (``LightningModule``) and `SimulatedLogDataModule`
  (``LightningDataModule`` over log files (`torchjfa.data.JointLog` with accelerations, or `torchjfa.sim.SimulatedLog`), split by time) train it,
  on one or several processes (DDP); ``python -m torchjfa.learning.cli fit --config cfg.yaml``
  is the command-line entry point (an example config is in ``torchjfa/learning/configs/``).
- `load_checkpoint` rebuilds the trained `ResidualDynamics` from a Lightning checkpoint without
  Lightning. The identified model itself is saved and loaded by `torchjfa.io`.
"""

from ..metrics import nmse as nmse  # re-exported: torchjfa.metrics is its home
from ._data import SimulatedLogDataModule as SimulatedLogDataModule
from ._data import StateTorqueDataset as StateTorqueDataset
from ._data import log_tensors as log_tensors
from ._data import time_split as time_split
from ._lightning import ResidualDynamicsModule as ResidualDynamicsModule
from ._lightning import load_checkpoint as load_checkpoint
from ._residual import MLP as MLP
from ._residual import JointResidual as JointResidual
from ._residual import ResidualDynamics as ResidualDynamics
from ._residual import state_features as state_features
