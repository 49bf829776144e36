"""Saving and loading identified rigid-body models, and results written whole.

One call writes everything needed to rebuild an identified model anywhere, one call reads it back
into a ready `torchjfa.dynamics.InverseDynamics`:

    >>> torchjfa.io.save_identified("head.npz", model, theta, output_noise=psi_y)  # doctest: +SKIP
    >>> idyn = torchjfa.io.load_identified("head.npz")        # InverseDynamics     # doctest: +SKIP

The file is a ``numpy.savez_compressed`` archive read with ``allow_pickle=False`` (no pickled
objects), format version 1:

=====================  ==================  =====================================================
key                    shape, dtype        meaning
=====================  ==================  =====================================================
``format``             (), str             ``"torchjfa.IdentifiedModel"``
``version``            (), int64           1
``library_version``    (), str             the writer's torchjfa version
``source_format``      (), str             ``"urdf"`` or ``"mjcf"``
``source_path``        (), str             the description's absolute path ("" if none)
``source_xml``         (), str             the description's text (loads without the path)
``gravity``            (3,), float64       gravity in the root frame, m/s^2
``friction``           (n_friction,), str  friction terms per joint (`ParameterLayout`)
``coulomb_velocity``   (), float64         the Coulomb term's smoothing velocity, rad/s (0:
                                           ``sign(qd)``; optional, files without it read as 0)
``transmission``       (), str             the drive train as JSON (`Transmission.to_dict`), or
                                           "" (none; optional, files without it read as none)
``joint_names``        (n_dof,), str       the layout's joint order
``parameter_names``    (n_params,), str    the layout's parameter names
``theta``              (n_params,), float  the identified parameters
``extra_<name>``       any                 user extras, e.g. noise estimates (numbers/strings)
=====================  ==================  =====================================================

One extra is read back with a meaning: ``extra_cutoff_hz``, the cut-off in Hz the logs were
filtered at when the model was identified (`torchjfa identify` stores it), which
`IdentifiedModel.cutoff_hz` gives so that new logs are prepared as the model's were.

The same content as a dictionary of tensors and Python values (`identified_to_dict`,
`identified_from_dict`) is what `torchjfa.learning` stores inside its Lightning checkpoints, so
that those load with ``torch.load(..., weights_only=True)``.

Every file and folder the library writes is written whole or not at all (`atomic_file`,
`output_folder`): a run killed at any moment leaves the earlier result as it was or the new one
complete, never a mix. A result folder ends with ``manifest.json`` (the library's version, the
command, each input's and each file's SHA-256); a folder holding other files is not replaced
unless asked (``overwrite``), and a second run writing the same folder meanwhile is refused.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ._util import MANIFEST, OutputError, atomic_file, check_output, output_folder
from ._util import library_version as _library_version
from .data import DEFAULT_CUTOFF_HZ
from .dynamics import FloatingBaseModel, InverseDynamics, RigidBodyModel

__all__ = [
    "IdentifiedModel",
    "save_identified",
    "read_identified",
    "load_identified",
    "identified_to_dict",
    "identified_from_dict",
    "output_folder",
    "atomic_file",
    "check_output",
    "OutputError",
    "MANIFEST",
]

_FORMAT = "torchjfa.IdentifiedModel"
_VERSION = 1
_EXTRA = "extra_"
_REQUIRED = frozenset(
    ("format", "version", "library_version", "source_format", "source_path", "source_xml")
    + ("gravity", "friction", "joint_names", "parameter_names", "theta")
)


@dataclass
class IdentifiedModel:
    """The content of an identified-model file.

    Attributes:
        model: the `RigidBodyModel` rebuilt from the stored description (a
            `torchjfa.dynamics.FloatingBaseModel` for a floating-base robot).
        theta: ``(n_params,)`` identified parameters (the stored dtype, float64 normally).
        extras: the user's extras, name -> ``torch.Tensor`` (numbers) or ``str``.
        library_version: the torchjfa version that wrote the file.
        source_path: the description's path when it was written (None if none).
        cutoff_hz: (read-only) the cut-off the model's logs were filtered at, Hz.
    """

    model: RigidBodyModel | FloatingBaseModel
    theta: torch.Tensor
    extras: dict[str, object] = field(default_factory=dict)
    library_version: str = ""
    source_path: str | None = None

    @property
    def cutoff_hz(self) -> float:
        """The cut-off the model's logs were filtered at, Hz: the ``cutoff_hz`` extra
        (`torchjfa identify` stores it), else `torchjfa.data.DEFAULT_CUTOFF_HZ` (a file
        without it, or one whose value is not a positive number). New logs judged against the
        model, or a payload's logs, are prepared at it so that both sides see the same filter.
        """
        stored = self.extras.get("cutoff_hz")
        try:
            value = float(stored) if stored is not None else math.nan
        except (TypeError, ValueError, RuntimeError):  # text, or several numbers
            value = math.nan
        return value if 0 < value < math.inf else DEFAULT_CUTOFF_HZ

    def inverse_dynamics(self, *, trainable: bool | str = False) -> InverseDynamics:
        """A ready `InverseDynamics` of ``model`` and ``theta`` (a fixed-base robot's)."""
        if isinstance(self.model, FloatingBaseModel):
            raise ValueError(
                "InverseDynamics is a fixed-base robot's module; use the FloatingBaseModel's "
                "inverse_dynamics(q, v, a, theta) for a floating base"
            )
        return InverseDynamics(self.model, self.theta, trainable=trainable)


def _unpack(model, theta) -> tuple[RigidBodyModel | FloatingBaseModel, torch.Tensor]:
    if isinstance(model, InverseDynamics):
        if theta is None:
            theta = model.theta.detach()
        model = model.model
    if not isinstance(model, RigidBodyModel | FloatingBaseModel):
        raise TypeError(
            "model must be a RigidBodyModel, a FloatingBaseModel or an InverseDynamics, got "
            f"{type(model)}"
        )
    if theta is None:
        raise ValueError("theta is required when model is a RigidBodyModel")
    theta = torch.as_tensor(theta).detach().cpu()
    if not theta.is_floating_point():
        theta = theta.to(torch.float64)
    if tuple(theta.shape) != (model.n_params,):
        raise ValueError(
            f"theta must have shape ({model.n_params},) for this model, got {tuple(theta.shape)}"
        )
    if not bool(torch.isfinite(theta).all()):
        raise ValueError("theta has NaN or infinite entries")
    return model, theta


def _check_extra(name: str, value) -> object:
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"extra names must be identifiers, got {name!r}")
    if isinstance(value, str):
        return value
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().clone()
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        raise TypeError(
            f"extra {name!r} must be a string, a number or an array of numbers, got "
            f"{type(value).__name__} (dtype {arr.dtype})"
        )
    return torch.as_tensor(arr.copy())


def identified_to_dict(model, theta=None, **extras) -> dict[str, object]:
    """The identified model as a dictionary of tensors, strings and lists (no custom classes).

    Args:
        model: a `RigidBodyModel` or a `torchjfa.dynamics.FloatingBaseModel`, or an
            `InverseDynamics` (its theta is the default).
        theta: ``(n_params,)`` parameters.
        **extras: numbers, arrays or strings stored alongside (e.g. ``output_noise=...``).

    Returns:
        A dict that `identified_from_dict` reads and ``torch.save`` / ``torch.load(...,
        weights_only=True)`` round-trip.

    Raises:
        TypeError: on a wrong model type or an extra that is neither numeric nor a string.
        ValueError: on a theta of the wrong shape or with non-finite entries.
    """
    model, theta = _unpack(model, theta)
    floating = isinstance(model, FloatingBaseModel)
    joints = model.joints if floating else model
    return {
        "format": _FORMAT,
        "version": _VERSION,
        "library_version": _library_version(),
        "source_format": joints.source_format,
        "source_path": joints.source_path or "",
        "source_xml": joints.source_xml,
        "gravity": joints.gravity,
        "friction": list(joints.friction),
        "coulomb_velocity": float(joints.coulomb_velocity),
        "transmission": json.dumps(t.to_dict()) if (t := joints.transmission) is not None else "",
        "floating_base": model.base_name if floating else "",
        "joint_names": list(model.joint_names),
        "parameter_names": list(model.parameter_names),
        "theta": theta.clone(),
        "extras": {k: _check_extra(k, v) for k, v in extras.items()},
    }


def _build_model(
    fmt: str, path: str, xml: str, gravity, friction, coulomb_velocity=0.0, transmission=""
) -> RigidBodyModel:
    if fmt not in ("urdf", "mjcf"):
        raise ValueError(f"unknown description format {fmt!r}; expected 'urdf' or 'mjcf'")
    build = RigidBodyModel.from_urdf if fmt == "urdf" else RigidBodyModel.from_mjcf
    gravity = [float(g) for g in torch.as_tensor(gravity).reshape(-1).tolist()]
    # the stored path is used only while it still holds the same description (MJCF includes
    # and mesh paths resolve relative to it); otherwise the stored text itself is compiled
    source = xml
    if path and Path(path).is_file() and Path(path).read_text() == xml:
        source = path
    model = build(
        source, friction=tuple(friction), gravity=gravity, coulomb_velocity=float(coulomb_velocity)
    )
    if str(transmission):
        model = model.with_transmission(json.loads(str(transmission)))
    return model


def identified_from_dict(data: dict) -> IdentifiedModel:
    """Inverse of `identified_to_dict`.

    Raises:
        ValueError: if the dict is not an identified model of a known version, or the stored
            description no longer gives the stored parameter layout.
    """
    if not isinstance(data, dict) or data.get("format") != _FORMAT:
        raise ValueError("not a torchjfa identified model (missing or wrong 'format' entry)")
    missing = sorted(_REQUIRED - set(data))
    if missing:
        raise ValueError(f"not a complete torchjfa identified model: {missing} missing")
    if int(data["version"]) != _VERSION:
        raise ValueError(f"unsupported identified-model version {int(data['version'])}")
    model = _build_model(
        str(data["source_format"]),
        str(data["source_path"]),
        str(data["source_xml"]),
        data["gravity"],
        [str(f) for f in data["friction"]],
        data.get("coulomb_velocity", 0.0),
        data.get("transmission", ""),
    )
    base = str(data.get("floating_base", ""))
    if base:  # the stored description is the fixed-base text of the joints (no free joint)
        model = FloatingBaseModel(model, base_name=base)
    names = tuple(str(n) for n in data["parameter_names"])
    if model.parameter_names != names:
        raise ValueError(
            "the stored description gives a different parameter layout than the stored one "
            f"({len(model.parameter_names)} vs {len(names)} parameters)"
        )
    theta = torch.as_tensor(data["theta"]).clone()
    if tuple(theta.shape) != (model.n_params,) or not theta.is_floating_point():
        raise ValueError(
            f"the stored theta has shape {tuple(theta.shape)} and dtype {theta.dtype}; the "
            f"stored description needs ({model.n_params},) floating point"
        )
    return IdentifiedModel(
        model=model,
        theta=theta,
        extras=dict(data.get("extras", {})),
        library_version=str(data["library_version"]),
        source_path=str(data["source_path"]) or None,
    )


def save_identified(path: str | os.PathLike, model, theta=None, **extras) -> None:
    """Write an identified model to ``path`` (the module's ``.npz`` format).

    Args:
        path: the file to write (``numpy`` appends nothing: the name is used as given).
        model: a `RigidBodyModel`, or an `InverseDynamics` (its theta is the default).
        theta: ``(n_params,)`` identified parameters.
        **extras: numbers, arrays or strings to keep with the model, e.g. noise estimates
            ``input_noise=(n_params,)``, ``output_noise=()`` (N^2 m^2), ``estimator="BayesianJFA"``.

    The file is written whole or not at all: a run killed while writing leaves the earlier
    file (if any) as it was.

    Raises:
        TypeError, ValueError: as `identified_to_dict`.
        torchjfa.io.OutputError: ``path`` is a folder or a symbolic link.
    """
    data = identified_to_dict(model, theta, **extras)
    arrays: dict[str, np.ndarray] = {}
    for key, value in data.items():
        if key == "extras":
            continue
        if isinstance(value, torch.Tensor):
            arrays[key] = value.numpy()
        elif isinstance(value, list):
            arrays[key] = np.array(value, dtype=np.str_).reshape(len(value))
        elif isinstance(value, int):
            arrays[key] = np.array(value, dtype=np.int64)
        else:
            arrays[key] = np.array(value)
    for key, value in data["extras"].items():
        arrays[_EXTRA + key] = np.array(value) if isinstance(value, str) else value.numpy()
    with atomic_file(path) as tmp, open(tmp, "wb") as fh:  # whole, or the earlier file kept
        np.savez_compressed(fh, **arrays)


def read_identified(path: str | os.PathLike) -> IdentifiedModel:
    """Read a file written by `save_identified` (the model, theta, extras, writer's version).

    Raises:
        FileNotFoundError: if the file does not exist.
        ValueError: if it is not an identified-model file of a known version, or a damaged one
            (truncated, empty, bit-flipped, another program's file): one message that names the
            file, the reason and what to do, whatever the archive reader raised.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no model file {path!r}")
    try:
        return identified_from_dict(_read_arrays(path))
    except (FileNotFoundError, IsADirectoryError, PermissionError):
        raise
    except Exception as exc:  # a damaged archive raises many kinds (zip, zlib, npy header, ...)
        reason = " ".join(str(exc).split())[:200]  # one line, whatever the reader said
        if type(exc) is not ValueError:
            reason = f"{type(exc).__name__}: {reason}" if reason else type(exc).__name__
        raise ValueError(
            f"{path!r} is not a torchjfa model file, or it is damaged ({reason}); write it "
            "again with `torchjfa identify ... --out DIR` or torchjfa.io.save_identified"
        ) from exc


def _read_arrays(path: str) -> dict[str, object]:
    """The archive's arrays as `identified_from_dict`'s dict (raises whatever the reader does)."""
    with open(path, "rb") as fh:  # ours to close, also when the archive reader fails
        magic = fh.read(4)
        if not magic:
            raise ValueError("the file is empty")
        if magic not in (b"PK\x03\x04", b"PK\x05\x06"):  # a zip archive's first record
            raise ValueError(f"not an .npz (zip) archive: it starts with {magic!r}")
        fh.seek(0)
        with np.load(fh, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    if "format" not in arrays or str(arrays["format"]) != _FORMAT:
        raise ValueError("no 'format' entry naming a torchjfa identified model")
    data: dict[str, object] = {"extras": {}}
    for key, arr in arrays.items():
        if key.startswith(_EXTRA):
            name = key[len(_EXTRA) :]
            data["extras"][name] = str(arr) if arr.dtype.kind == "U" else torch.from_numpy(arr)
        elif key in ("friction", "joint_names", "parameter_names"):
            data[key] = [str(s) for s in arr.tolist()]
        elif arr.dtype.kind == "U":
            data[key] = str(arr)
        elif key == "version":
            data[key] = int(arr)
        else:
            data[key] = torch.from_numpy(arr)
    return data


def load_identified(path: str | os.PathLike, *, trainable: bool | str = False) -> InverseDynamics:
    """Load a file written by `save_identified` into a ready `InverseDynamics`.

    Args:
        path: the ``.npz`` file.
        trainable: False (frozen), True or ``"consistent"`` (trained through the consistent
            parametrisation: every step stays physically consistent) or ``"unconstrained"``
            (theta itself; see `InverseDynamics`).

    Returns:
        ``InverseDynamics(model, theta)`` giving bitwise the torques of the saved model.

    Raises:
        FileNotFoundError: if the file does not exist.
        ValueError: if the file is not a torchjfa model file or is damaged (`read_identified`).
    """
    return read_identified(path).inverse_dynamics(trainable=trainable)
