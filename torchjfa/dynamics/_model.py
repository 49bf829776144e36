"""`RigidBodyModel`: a robot read from URDF or MJCF, its parameter layout and batched regressor.

Use this module to turn a robot description and joint logs into regression data: the
regressor ``Y(q, qd, qdd)`` with ``tau = Y theta``, the streamed chunks of its rows, or directly
the `Moments` an estimator fits. `InverseDynamics` wraps a model and a theta as an
``nn.Module``; `torchjfa.dynamics._parameters` holds the layout and inertial conversions.
"""

from __future__ import annotations

import contextlib
import copy
import os
from collections.abc import Iterator, Sequence

import numpy as np
import torch

from .._util import note, progress_bar, single_thread
from .._validation import as_tensor
from ..stats import CHUNK_SIZE, Moments
from ._inputs import check_chunk, check_out, check_state, new_output
from ._kernel import RegressorKernel
from ._kinematics import FrameKinematics
from ._mjcf import tree_from_mjcf
from ._parameters import (
    BodyInertial,
    check_coulomb_velocity,
    friction_kinds,
    inertial_from_vector,
    inertial_vector,
)
from ._rnea import TreeConstants, regressor_into
from ._rnea_fast import regressor_fast
from ._transmission import Transmission, apply_joint_terms, layout_for, read_transmission
from ._tree import KinematicTree, describe_source, read_description, tree_from_urdf
from ._urdf import fix_urdf_joints

__all__ = ["RigidBodyModel", "BodyInertial"]

_DEFAULT_CHUNK = 1024
_COMPILED_DTYPES = (torch.float64, torch.float32)


class RigidBodyModel(FrameKinematics):
    """A fixed-base tree of rigid bodies with revolute and prismatic joints.

    Build it with `from_urdf` or `from_mjcf`. theta is laid out joint by joint in
    `joint_names` order: the 10 inertial parameters of the body the joint moves
    ``[m, m cx, m cy, m cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (about the body frame origin, in the
    body frame: the URDF child link frame or the MJCF body frame, with bodies attached by fixed
    joints lumped in), then the joint's friction terms (see `ParameterLayout`).
    `forward_kinematics` places any frame of the description (`frame_names`).

    Attributes:
        joint_names: the actuated joints, in pytorch-kinematics' order (depth first).
        joint_types: ``"revolute"`` (URDF revolute/continuous, MJCF hinge) or ``"prismatic"``.
        body_names: the body each joint moves.
        layout: the `ParameterLayout` of theta.
        chain: the pytorch-kinematics chain (float32, as pytorch-kinematics builds it; for a
            URDF from its links and joints only, without visuals).
        source_path: the description's absolute path, or None when built from a string.
        source_format: ``"urdf"`` or ``"mjcf"``.
        source_xml: the description's text.
        coulomb_velocity: the Coulomb term's smoothing velocity ``v_c``, rad/s (m/s for
            prismatic joints): its regressor column is ``tanh(qd / v_c)``, or ``sign(qd)`` for
            ``v_c = 0`` (the default). Real joints' dry friction changes sign over a band of
            velocities (a few hundredths of a rad/s on a geared arm such as the Panda),
            which ``sign`` draws as a jump; `with_coulomb_velocity` gives the same model with
            another ``v_c``, `torchjfa.data.choose_cutoff` chooses it from a log.
        transmission: the `Transmission` whose motors carry the joint terms of the joints it
            drives (`with_transmission`), or None.
    """

    def __init__(
        self,
        tree: KinematicTree,
        chain,
        *,
        friction: str | Sequence[str],
        source_xml: str,
        source_path: str | None,
        source_format: str,
        coulomb_velocity: float = 0.0,
    ) -> None:
        self._tree = tree
        self.coulomb_velocity = check_coulomb_velocity(coulomb_velocity)
        self.chain = chain
        self.transmission: Transmission | None = None
        self.layout = layout_for(tree.joint_names, friction_kinds(friction), None)
        self.source_xml = source_xml
        self.source_path = source_path
        self.source_format = source_format
        self._constants: dict[tuple[torch.dtype, torch.device], TreeConstants] = {}
        self._kernels: dict[torch.dtype, RegressorKernel | None] = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_urdf(
        cls,
        source: str | bytes | os.PathLike,
        *,
        friction: str | Sequence[str] = ("viscous",),
        gravity: Sequence[float] = (0.0, 0.0, -9.81),
        fixed_joints: str | Sequence[str] = (),
        coulomb_velocity: float = 0.0,
    ) -> RigidBodyModel:
        """Read a URDF file (or a string or bytes of URDF XML).

        The description must be one fixed-base tree: one root link, each other link the child
        of one joint, at least one revolute, continuous or prismatic joint, none of them a
        ``<mimic>`` joint. Meshes are never read (``package://`` paths need not resolve);
        ``<transmission>``, ``<ros2_control>``, ``<gazebo>`` and other tags are ignored.

        Args:
            source: a path to a ``.urdf`` file, or the XML itself (``str`` or ``bytes``; an
                ``<?xml ... encoding="..."?>`` declaration is honoured).
            friction: friction terms per joint, from ``("viscous", "coulomb", "offset")``.
            gravity: ``(3,)`` gravity in the root link's frame, m/s^2.
            fixed_joints: joints held at q = 0 and treated as ``fixed`` (their links lumped into
                the parent), e.g. a gripper's fingers to identify the arm alone; `source_xml`
                is then the description with these joints turned fixed.
            coulomb_velocity: the Coulomb column's smoothing velocity (see the class).

        Raises:
            FileNotFoundError: if the file does not exist.
            ValueError: on malformed XML or numbers, floating/planar or unknown joint types,
                undefined links, several root links, kinematic loops, no moving joint, mimic
                joints, or a ``fixed_joints`` name that is no joint; the message names the file.
        """
        text, path = read_description(source, "URDF")
        where = describe_source("URDF", path)
        text = fix_urdf_joints(text, fixed_joints, where)
        tree, chain = tree_from_urdf(text, gravity, where)
        return cls(
            tree,
            chain,
            friction=friction,
            source_xml=text,
            source_path=path,
            source_format="urdf",
            coulomb_velocity=coulomb_velocity,
        )

    @classmethod
    def from_mjcf(
        cls,
        source: str | bytes | os.PathLike,
        *,
        friction: str | Sequence[str] = ("viscous",),
        gravity: Sequence[float] | None = None,
        coulomb_velocity: float = 0.0,
    ) -> RigidBodyModel:
        """Read an MJCF file (or a string or bytes of MJCF XML); MuJoCo compiles it.

        Args:
            source: a path to an MJCF ``.xml`` file, or the XML itself (``str`` or ``bytes``).
            friction: friction terms per joint, from ``("viscous", "coulomb", "offset")``.
            gravity: ``(3,)`` m/s^2; None takes the file's ``<option gravity>`` (MuJoCo's
                default is ``(0, 0, -9.81)``).
            coulomb_velocity: the Coulomb column's smoothing velocity (see the class).

        Raises:
            FileNotFoundError: if the file does not exist.
            ValueError: on free or ball joints, bodies with several joints, unnamed joints,
                active equality constraints, or XML that MuJoCo cannot compile.
        """
        text, path = read_description(source, "MJCF")
        tree, chain, _ = tree_from_mjcf(text, path, gravity)
        return cls(
            tree,
            chain,
            friction=friction,
            source_xml=text,
            source_path=path,
            source_format="mjcf",
            coulomb_velocity=coulomb_velocity,
        )

    # ------------------------------------------------------------------ description
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._tree.joint_names

    @property
    def joint_types(self) -> tuple[str, ...]:
        return self._tree.joint_types

    @property
    def body_names(self) -> tuple[str, ...]:
        return self._tree.body_names

    @property
    def lumped_bodies(self) -> dict[str, tuple[str, ...]]:
        """Per joint, the frames attached by fixed joints that are lumped into its body."""
        return dict(zip(self.joint_names, self._tree.lumped, strict=True))

    @property
    def parents(self) -> tuple[int, ...]:
        """Per joint, the index of the joint that moves its parent body (-1: the fixed base)."""
        return self._tree.parent

    @property
    def n_dof(self) -> int:
        return len(self._tree.joint_names)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return self.layout.parameter_names

    @property
    def n_params(self) -> int:
        return self.layout.n_params

    @property
    def friction(self) -> tuple[str, ...]:
        return self.layout.friction

    @property
    def gravity(self) -> torch.Tensor:
        """``(3,)`` float64, m/s^2, in the root frame."""
        return torch.as_tensor(self._tree.gravity, dtype=torch.float64).clone()

    @property
    def nominal_theta(self) -> torch.Tensor:
        """``(n_params,)`` float64: the description's inertials, zero friction."""
        inertial = torch.as_tensor(self._tree.inertial, dtype=torch.float64)
        return self.layout.join(inertial)

    @property
    def description_theta(self) -> torch.Tensor:
        """``(n_params,)``: the description with its stated damping, friction and armature."""
        from ._described import description_theta

        return description_theta(self)

    def __repr__(self) -> str:
        where = self.source_path or "<string>"
        smooth = f", coulomb_velocity={self.coulomb_velocity:g}" if self.coulomb_velocity else ""
        return (
            f"RigidBodyModel({self.source_format}: {where}, n_dof={self.n_dof}, "
            f"n_params={self.n_params}, friction={self.friction}{smooth})"
        )

    def with_coulomb_velocity(self, coulomb_velocity: float) -> RigidBodyModel:
        """A new `RigidBodyModel`, the same robot, parameter layout and compiled kernels, with
        the Coulomb column ``tanh(qd / v_c)``, ``coulomb_velocity`` = ``v_c`` >= 0, rad/s (m/s
        prismatic); 0 gives ``sign(qd)``."""
        other = copy.copy(self)
        other.coulomb_velocity = check_coulomb_velocity(coulomb_velocity)
        return other

    def with_joint_terms(self, friction: str | Sequence[str]) -> RigidBodyModel:
        """The same robot with other joint terms (`FRICTION_KINDS`), its Coulomb velocity and
        transmission kept."""
        other = copy.copy(self)
        other.layout = layout_for(self.joint_names, friction_kinds(friction), self.transmission)
        other._kernels = {}  # the compiled kernel holds the joint terms
        return other

    def with_transmission(self, transmission) -> RigidBodyModel:
        """The same robot with its joint terms on the motors of ``transmission`` (a
        `Transmission`, a JSON/YAML file or a mapping; None: on the joints). Theta keeps its
        length; the motors' terms take their first joint's places and names.

        Raises:
            ValueError: on a transmission naming joints the robot does not have.
        """
        transmission = read_transmission(transmission)
        if transmission is not None:
            transmission.indices(self.joint_names)
        other = copy.copy(self)
        other.transmission = transmission
        other.layout = layout_for(self.joint_names, self.friction, transmission)
        return other

    # ------------------------------------------------------------------ regressor
    def _consts(self, dtype: torch.dtype, device: torch.device) -> TreeConstants:
        key = (dtype, device)
        if key not in self._constants:
            self._constants[key] = TreeConstants.from_tree(self._tree, dtype, device)
        return self._constants[key]

    def _check_state(self, q, qd, qdd, tau=None) -> list[torch.Tensor]:
        return check_state(q, qd, qdd, tau, joint_names=self.joint_names)

    def regressor(
        self,
        q,
        qd,
        qdd,
        *,
        chunk_size: int | None = None,
        out: torch.Tensor | None = None,
        compiled: bool | None = None,
    ) -> torch.Tensor:
        """The dynamics regressor: ``tau = Y(q, qd, qdd) @ theta``.

        Args:
            q: ``(*batch, n_dof)`` joint positions, rad (revolute) or m (prismatic).
            qd: ``(*batch, n_dof)`` joint velocities, rad/s or m/s.
            qdd: ``(*batch, n_dof)`` joint accelerations, rad/s^2 or m/s^2.
            chunk_size: samples computed at a time (memory/speed trade-off); None picks one.
                Ignored when an input requires grad (one pass, so autograd sees one graph) and
                by the compiled kernel (it works through the batch 8 or 16 samples at a time).
            out: optional contiguous ``(*batch, n_dof, n_params)`` tensor of the inputs' dtype
                and device to write into (no allocation: reusing one output across calls saves
                the first-touch cost of fresh memory); not with inputs that require grad.
            compiled: which path computes Y. The compiled path is a C++ kernel generated for
                this robot (`torchjfa.dynamics._codegen`: the same maths with the tree's
                constants folded in, several times faster than the torch path, see
                docs/benchmarks.md) for CPU float64/float32 inputs that do not require grad;
                it gives the torch path's result to about 1e-15 relative in float64 (1e-7 in
                float32). ``None`` (the default) takes it wherever it applies and a C++
                compiler is there; without a compiler, or if compiling fails, it says so once
                (the ``"torchjfa"`` logger) and runs the torch path. ``True`` insists (raises
                without a compiler); ``False`` always runs the torch path. The first compiled
                call per robot and dtype generates and compiles the kernel (``CXX`` or
                ``g++``; about 2 s for the Panda arm, with a note), later ones load it from a
                disk cache (``$TORCHJFA_CACHE_DIR``, default ``~/.cache/torchjfa``); see
                `compile_regressor`. The kernel uses ``torch.get_num_threads()`` threads on
                large batches, the torch path one intra-op thread.

        Returns:
            ``(*batch, n_dof, n_params)`` in the inputs' dtype and device (float64 for
            non-tensor input), ``out`` when given; differentiable with respect to q, qd and
            qdd (on the default path).

        Raises:
            ValueError: on wrong shapes, mismatched devices, NaN or infinite entries, or an
                ``out`` of the wrong shape, dtype or device, not contiguous, or with grad.
            RuntimeError: with ``compiled=True``, if no C++ compiler is found or compiling
                fails.
        """
        q, qd, qdd = self._check_state(q, qd, qdd)
        batch = q.shape[:-1]
        n = self.n_dof
        q2, qd2, qdd2 = (v.reshape(-1, n) for v in (q, qd, qdd))
        B = q2.shape[0]
        c = self._consts(q2.dtype, q2.device)
        grad = torch.is_grad_enabled() and any(v.requires_grad for v in (q2, qd2, qdd2))
        shape = (*batch, n, self.n_params)
        if out is not None:
            check_out(out, shape, q2, grad)
        if grad:
            Y = q2.new_zeros(B, n, self.n_params)
            regressor_into(Y, q2, qd2, qdd2, c, self.friction)
            self._joint_terms(Y, qd2, qdd2)
            return Y.reshape(shape)
        step = _DEFAULT_CHUNK if chunk_size is None else check_chunk(chunk_size)
        Y = new_output(q2, (B, n, self.n_params)) if out is None else out.view(B, n, -1)
        kernel = None
        if compiled is not False and q2.device.type == "cpu" and q2.dtype in _COMPILED_DTYPES:
            kernel = self._kernel(q2.dtype, required=bool(compiled))
        if kernel is not None:
            kernel(Y, q2, qd2, qdd2)  # writes every entry
        else:
            with single_thread() if q2.device.type == "cpu" else contextlib.nullcontext():
                regressor_fast(Y, q2, qd2, qdd2, c, self.friction, chunk_size=step)  # every entry
        self._joint_terms(Y, qd2, qdd2)
        return Y.reshape(shape) if out is None else out

    def _joint_terms(self, Y: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> None:
        """Finish the joint-term columns of ``Y (B, n, n_params)`` that every path writes as
        ``[qd, sign(qd), 1, qdd]``: Coulomb smoothing and the transmission's motors
        (`torchjfa.dynamics._transmission.apply_joint_terms`)."""
        apply_joint_terms(Y, qd, qdd, self.layout, self.coulomb_velocity, self.transmission)

    def _kernel(self, dtype: torch.dtype, *, required: bool = True) -> RegressorKernel | None:
        """The compiled kernel for ``dtype``; None when it cannot be built and not ``required``."""
        if self._kernels.get(dtype) is None and (required or dtype not in self._kernels):
            try:
                self._kernels[dtype] = RegressorKernel(self._tree, self.friction, dtype)
            except RuntimeError as exc:
                if required:
                    raise
                self._kernels[dtype] = None  # not again for this model and dtype
                note(
                    "the compiled regressor is not available here, so the slower torch path "
                    f"runs ({str(exc).splitlines()[0]})",
                    key="regressor-fallback",
                )
        return self._kernels[dtype]

    def compile_regressor(self, dtype: torch.dtype = torch.float64) -> float:
        """Build the kernel of ``regressor(..., compiled=True)`` for ``dtype`` now.

        The first compiled call does this itself; call it to pay the cost up front or to time
        it. Generating the C++ and compiling it takes about 2 s for the 7-DoF Panda arm (0.3 s
        for 4 joints, 3.5 s for the 9-DoF Panda), loading it from the disk cache a few ms.

        Args:
            dtype: torch.float64 or torch.float32.

        Returns:
            The seconds it took in this process (0 if already built).

        Raises:
            ValueError: for another dtype.
            RuntimeError: if no C++ compiler is found or compiling fails.
        """
        if dtype not in _COMPILED_DTYPES:
            raise ValueError(f"the compiled regressor supports float64 and float32, got {dtype}")
        if self._kernels.get(dtype) is not None:
            return 0.0
        return self._kernel(dtype).build_seconds

    def inverse_dynamics(self, q, qd, qdd, theta) -> torch.Tensor:
        """``tau = Y(q, qd, qdd) @ theta``, ``(*batch, n_dof)``; theta ``(n_params,)``."""
        Y = self.regressor(q, qd, qdd)
        theta = self._check_theta(theta).to(Y)
        return Y @ theta

    def regressor_chunks(
        self, q, qd, qdd, tau, *, chunk_size: int = CHUNK_SIZE, compiled: bool | None = None
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """Stream the stacked regression rows, ``chunk_size`` samples at a time.

        Args:
            q: ``(*batch, n_dof)`` positions; the batch is flattened.
            qd: ``(*batch, n_dof)`` velocities.
            qdd: ``(*batch, n_dof)`` accelerations.
            tau: ``(*batch, n_dof)`` torques, N m (N).
            chunk_size: samples per chunk.
            compiled: compute each chunk with the compiled kernel (see `regressor`).

        Yields:
            ``(Y_rows, tau_rows)``: ``(chunk * n_dof, n_params)`` and ``(chunk * n_dof,)``,
            rows ordered sample by sample, joint by joint within a sample.
        """
        q, qd, qdd, tau = self._check_state(q, qd, qdd, tau)
        step = check_chunk(chunk_size)
        n = self.n_dof
        q2, qd2, qdd2, tau2 = (v.reshape(-1, n) for v in (q, qd, qdd, tau))
        for s in range(0, q2.shape[0], step):
            e = min(q2.shape[0], s + step)
            Y = self.regressor(q2[s:e], qd2[s:e], qdd2[s:e], chunk_size=step, compiled=compiled)
            yield Y.reshape(-1, self.n_params), tau2[s:e].reshape(-1)

    def moments(
        self,
        q,
        qd,
        qdd,
        tau,
        *,
        chunk_size: int = CHUNK_SIZE,
        progress: bool = False,
        compiled: bool | None = None,
    ) -> Moments:
        """`Moments` of ``tau ~ Y theta`` over all samples, never holding the whole Y.

        Args:
            q: ``(*batch, n_dof)`` positions.
            qd: ``(*batch, n_dof)`` velocities.
            qdd: ``(*batch, n_dof)`` accelerations.
            tau: ``(*batch, n_dof)`` torques.
            chunk_size: samples per chunk (memory is O(chunk_size * n_dof * n_params)).
            progress: show a progress bar.
            compiled: compute the regressor with the compiled kernel (see `regressor`).

        Returns:
            `Moments` with ``n_features = n_params`` and one row per sample and joint.
        """
        q, qd, qdd, tau = self._check_state(q, qd, qdd, tau)
        total = int(np.prod(q.shape[:-1]))
        if total == 0:
            raise ValueError("no samples: q has an empty batch")
        m = Moments.zeros(self.n_params, device=q.device)
        with progress_bar(total=total, desc="moments", enabled=progress, unit="sample") as bar:
            chunks = self.regressor_chunks(
                q, qd, qdd, tau, chunk_size=chunk_size, compiled=compiled
            )
            for Y, t in chunks:
                m.update(Y, t)
                bar.update(Y.shape[0] // self.n_dof)
        return m

    # ------------------------------------------------------------------ inertials
    def _check_theta(self, theta) -> torch.Tensor:
        theta = as_tensor(theta, name="theta")
        if theta.shape != (self.n_params,):
            raise ValueError(
                f"theta must have shape ({self.n_params},) for this model, got {tuple(theta.shape)}"
            )
        return theta

    def inertials(self, theta=None) -> tuple[BodyInertial, ...]:
        """Mass, centre of mass and inertia at the centre of mass of each joint's body.

        Args:
            theta: ``(n_params,)``; default `nominal_theta`.

        Raises:
            ValueError: if a body's mass is not positive (its centre of mass is undefined).
        """
        theta = self.nominal_theta if theta is None else self._check_theta(theta)
        inertial, _ = self.layout.split(theta)
        out = []
        for k, (joint, body) in enumerate(zip(self.joint_names, self.body_names, strict=True)):
            if not bool(inertial[k, 0] > 0):
                raise ValueError(
                    f"the body {body!r} moved by joint {joint!r} has mass "
                    f"{float(inertial[k, 0])}; a positive mass is needed to define its centre of "
                    "mass"
                )
            mass, com, inertia = inertial_from_vector(inertial[k])
            out.append(BodyInertial(joint, body, mass, com, inertia))
        return tuple(out)

    def theta_from_inertials(
        self, inertials: Sequence[BodyInertial], friction=None
    ) -> torch.Tensor:
        """Inverse of `inertials`: theta ``(n_params,)`` (float64) with the given friction.

        Args:
            inertials: one `BodyInertial` per joint, in `joint_names` order (or matched by
                their ``joint`` names).
            friction: ``(n_dof, n_friction)`` friction terms; default zeros.
        """
        by_name = {b.joint: b for b in inertials}
        missing = [j for j in self.joint_names if j not in by_name]
        if missing or len(inertials) != self.n_dof:
            raise ValueError(
                f"need one BodyInertial per joint of {self.joint_names}; missing {missing}"
            )
        rows = []
        for j in self.joint_names:
            b = by_name[j]
            mass = as_tensor(b.mass, name="mass", dtype=torch.float64)
            com = as_tensor(b.com, name="com", dtype=torch.float64)
            inertia = as_tensor(b.inertia, name="inertia", dtype=torch.float64)
            if mass.shape != () or com.shape != (3,) or inertia.shape != (3, 3):
                raise ValueError(f"BodyInertial of {j!r}: need mass (), com (3,), inertia (3, 3)")
            rows.append(inertial_vector(mass, com, inertia))
        fr = None if friction is None else as_tensor(friction, name="friction", dtype=torch.float64)
        return self.layout.join(torch.stack(rows), fr)

    def write_urdf(self, theta, path: str | os.PathLike) -> None:
        """Write the description with theta's inertials (URDF models); see `_writeback`."""
        from ._writeback import write_urdf

        write_urdf(self, theta, path)

    def write_mjcf(self, theta, path: str | os.PathLike) -> None:
        """Write the description with theta's inertials as MJCF (a URDF model through MuJoCo's URDF
        importer); see `_writeback`."""
        from ._writeback import write_mjcf

        write_mjcf(self, theta, path)
