"""An excitation designed, compared and written: what ``torchjfa excite`` produces.

`design_excitation` runs `optimize_excitation` and, for comparison, the library's random sum of
sinusoids in the same limits about the same posture (`random_excitation`), with both
trajectories' information (`trajectory_information`) and the random one's margins to the limits.
`ExcitationDesign.write` puts it in a folder: ``trajectory.npz`` (the `FourierTrajectory` and
its samples, what ``torchjfa simulate --trajectory`` tracks), ``trajectory.csv`` (t, q, qd, qdd),
``coefficients.json``, ``report.json``, ``report.md`` (the margins left to every limit, in
physical units, against the random excitation's) and the figures.
"""

from __future__ import annotations

import inspect
import json
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._util import output_folder
from ..dynamics import RigidBodyModel
from ._check import check_limits, physical_margins, trajectory_geometry
from ._design import DEFAULT_RATE, ExcitationResult, optimize_excitation, random_excitation
from ._fourier import FourierTrajectory
from ._information import trajectory_information
from ._limits import Limits

__all__ = ["ExcitationDesign", "design_excitation"]


@dataclass(frozen=True)
class ExcitationDesign:
    """An optimised excitation beside a random one in the same limits (`design_excitation`).

    Attributes:
        robot: the robot's name, for the report.
        model: the robot's `RigidBodyModel`.
        result: `optimize_excitation`'s `ExcitationResult`.
        random: the random excitation (a `torchjfa.sim.SinusoidTrajectory`).
        random_margins: its margins to the limits: ``{"fraction": check_limits's,
            "physical": physical_margins'}``.
        information: ``{"optimised": ..., "random": ...}``, each `trajectory_information`'s
            dict.
        duration: the experiment's length, s.
        rate: the output rate, Hz (the limits were checked at 10x).
        payload: the link whose payload the design was for, or None (the robot's parameters).
    """

    robot: str
    model: RigidBodyModel
    result: ExcitationResult
    random: object
    random_margins: dict
    information: dict
    duration: float
    rate: float
    payload: str | None = None

    @property
    def trajectory(self) -> FourierTrajectory:
        """The optimised trajectory."""
        return self.result.trajectory

    def summary(self, command: str = "") -> dict:
        """``report.json``'s content: the command, the design's settings and both
        trajectories' numbers (their singular values left out)."""
        res, info = self.result, self.information
        traj = res.trajectory
        return {
            "robot": self.robot,
            "command": command,
            "payload": self.payload,
            "criterion": res.criterion,
            "duration_s": self.duration,
            "base_frequency_hz": traj.base_frequency,
            "harmonics": traj.harmonics,
            "rate_hz": self.rate,
            "identifiable_directions": int(res.basis.shape[1]),
            "n_params": self.model.n_params,
            "optimisation_seconds": res.seconds,
            "start_values": res.start_values,
            "shrink": res.shrink,
            "margins": {"optimised": res.margins, "random": self.random_margins["fraction"]},
            "physical_margins": {
                "optimised": res.physical_margins,
                "random": self.random_margins["physical"],
            },
            "geometry": res.geometry,
            "posture": traj.posture.tolist(),
            "posture_moved": res.posture_moved,
            "optimised": {k: v for k, v in info["optimised"].items() if k != "singular_values"},
            "random": {k: v for k, v in info["random"].items() if k != "singular_values"},
        }

    def headline(self) -> str:
        """One line: the criterion and condition number against the random excitation's."""
        res = self.result
        o, r = self.information["optimised"], self.information["random"]
        return (
            f"optimised a {self.duration:g} s excitation of {self.model.n_dof} joints in "
            f"{res.seconds:.1f} s: criterion {res.criterion} {o[res.criterion]:.4g} (random "
            f"{r[res.criterion]:.4g}), condition number {o['condition_number']:.4g} (random "
            f"{r['condition_number']:.4g}, {r['condition_number'] / o['condition_number']:.2f}x)"
        )

    def write(
        self,
        folder,
        *,
        plots: bool = True,
        command: str = "",
        overwrite: bool = False,
        inputs: Iterable[str | os.PathLike] = (),
    ) -> dict[str, Path]:
        """Write the trajectory, its coefficients, the report and (``plots``) the figures, as
        one unit (`torchjfa.io.output_folder`).

        Args:
            folder: the output folder (created; an earlier result in it is replaced whole).
            plots: write ``trajectory.png`` and ``singular_values.png``.
            command: the command line that made it, for the report and the manifest.
            overwrite: replace ``folder`` even where it holds files the library did not write.
            inputs: the description it was designed for, hashed into the manifest.

        Returns:
            Name -> path of what was written.
        """
        out = Path(folder)
        with output_folder(out, overwrite=overwrite, inputs=inputs, command=command) as stage:
            paths = _write_trajectory(stage, self.model, self.trajectory, self.rate, self.duration)
            summary = self.summary(command)
            paths["json"] = stage / "report.json"
            paths["json"].write_text(json.dumps(summary, indent=1))
            paths["markdown"] = stage / "report.md"
            paths["markdown"].write_text(_markdown(summary, self.result.limits))
            if plots:
                paths.update(
                    _plots(stage, self.model, self.result.limits, self.trajectory, self.random,
                           self.information, self.rate, self.duration)
                )  # fmt: skip
        return {key: out / path.name for key, path in paths.items()}


def design_excitation(
    model: RigidBodyModel,
    limits: Limits,
    *,
    robot: str = "robot",
    rate: float = DEFAULT_RATE,
    **options,
) -> ExcitationDesign:
    """Optimise an excitation and compare it with a random one in the same limits.

    Args:
        model: the robot.
        limits: the `Limits` (`limits_from_model`).
        robot: the robot's name, for the report.
        rate: output rate, Hz (the limits are checked at 10x).
        **options: `optimize_excitation`'s keywords (``duration``, ``base_frequency``,
            ``harmonics``, ``criterion``, ``posture``, ``n_grid``, ``n_starts``, ``seed``,
            ``payload``, ...).

    Returns:
        The `ExcitationDesign`.

    Raises:
        ValueError: on bad options or limits that cannot be met.
    """
    res = optimize_excitation(model, limits, rate=rate, **options)
    traj = res.trajectory
    # what was optimised: the options given over `optimize_excitation`'s own defaults
    chosen = {
        name: p.default
        for name, p in inspect.signature(optimize_excitation).parameters.items()
        if p.default is not inspect.Parameter.empty
    } | options
    rnd = random_excitation(
        model, limits, base_frequency=traj.base_frequency, harmonics=traj.harmonics, rate=rate,
        seed=chosen["seed"], posture=traj.posture,
    )  # fmt: skip
    geometry = trajectory_geometry(model, rnd, limits)
    margins = {
        "fraction": check_limits(model, rnd, limits, rate=rate, raise_error=False,
                                 geometry=geometry),
        "physical": physical_margins(model, rnd, limits, rate=rate, geometry=geometry),
    }  # fmt: skip
    n_info = max(chosen["n_grid"], 1000)
    info = {
        "optimised": trajectory_information(model, traj, res.basis, n_grid=n_info),
        "random": trajectory_information(model, rnd, res.basis, n_grid=n_info),
    }
    return ExcitationDesign(
        robot, model, res, rnd, margins, info, float(chosen["duration"]), float(rate),
        chosen["payload"],
    )  # fmt: skip


def _write_trajectory(out: Path, model, traj, rate: float, duration: float) -> dict[str, Path]:
    """``trajectory.npz`` (the `FourierTrajectory` and its samples), ``trajectory.csv`` (t, q,
    qd, qdd at ``rate`` Hz over ``duration`` s) and ``coefficients.json`` into ``out``."""
    t = np.arange(int(round(duration * rate))) / rate
    q, qd, qdd = traj.evaluate_numpy(t)
    sig = {"q": q, "qd": qd, "qdd": qdd}
    names = model.joint_names
    paths = {k: out / f for k, f in (("trajectory", "trajectory.npz"),
                                     ("csv", "trajectory.csv"),
                                     ("coefficients", "coefficients.json"))}  # fmt: skip
    traj.save(paths["trajectory"], t=t, joint_names=np.array(names), rate=rate, **sig)
    header = ["t"] + [f"{k}_{j}" for k in ("q", "qd", "qdd") for j in names]
    cols = np.column_stack([t] + [sig[k] for k in ("q", "qd", "qdd")])
    np.savetxt(paths["csv"], cols, delimiter=",", header=",".join(header), comments="")
    coef = {
        "form": "q_j(t) = q0_j + sum_k b_jk/(w k) + a_jk/(w k) sin(w k t) - b_jk/(w k) cos(w k t), "
        "w = 2 pi base_frequency",
        "base_frequency_hz": traj.base_frequency,
        "joint_names": list(names),
        "posture": traj.posture.tolist(),
        "a": traj.a.tolist(),
        "b": traj.b.tolist(),
    }
    paths["coefficients"].write_text(json.dumps(coef, indent=1))
    return paths


def _markdown(s: dict, limits) -> str:
    """``report.md``: the settings, both excitations' criteria and the margins."""
    o, r = s["optimised"], s["random"]
    lines = [
        f"# Excitation for {s['robot']}",
        "",
        f"`{s['command']}`",
        "",
        f"{s['duration_s']:g} s, base frequency {s['base_frequency_hz']:g} Hz, "
        f"{s['harmonics']} harmonics, output at {s['rate_hz']:g} Hz (limits checked at "
        f"{10 * s['rate_hz']:g} Hz); {s['identifiable_directions']} identifiable directions of "
        f"{s['n_params']} parameters; optimised in {s['optimisation_seconds']:.1f} s "
        f"(starts reached {', '.join(f'{v:.4g}' for v in s['start_values'])}; shrunk x"
        f"{s['shrink']:.3f} to hold the limits on the fine grid).",
        "",
        "| | optimised | random sum of sinusoids | ratio |",
        "| --- | ---: | ---: | ---: |",
        f"| condition number of Y V | {o['condition_number']:.4g} | "
        f"{r['condition_number']:.4g} | {r['condition_number'] / o['condition_number']:.2f} |",
    ]
    for k, label in (("d", "-log det M / r"), ("condition", "log cond"), ("e", "-log lambda_min")):
        lines.append(f"| {label} (`{k}`) | {o[k]:.4g} | {r[k]:.4g} | |")
    lines += _margin_lines(s, limits)
    return "\n".join(lines) + "\n"


def _margin_lines(s: dict, limits) -> list[str]:
    """The report's margins: per limit in physical units, per joint the peaks, the geometry."""
    phys, rnd = s["physical_margins"]["optimised"], s["physical_margins"]["random"]
    lines = ["", f"Smallest margin to each limit on the {10 * s['rate_hz']:g} Hz grid (position: "
             "to the limits with their margin; floor and collision: beyond the distance "
             "required there):", "", "| limit | margin | where | t [s] | random |",
             "| --- | ---: | --- | ---: | ---: |"]  # fmt: skip
    for kind in s["margins"]["optimised"]:
        e, r = phys.get(kind, {}), rnd.get(kind, {})
        margin = f"{e.get('margin', math.nan):.3g} {e.get('unit', '')}"
        if "required" in e:
            apart = (">= " if e.get("at_least") else "") + f"{e['distance']:.3g} m"
            margin += f" (apart {apart}, {e['required']:.3g} m required)"
        lines.append(f"| {kind} | {margin} | {e.get('where', '')} | {e.get('t', math.nan):.3f} | "
                     f"{r.get('margin', math.nan):.3g} {r.get('unit', '')} |")  # fmt: skip
    lines += ["", "Limits (position with the margin) and the optimised motion's peaks:", "",
              "| joint | low | high | peak / limit velocity | peak / limit acceleration | "
              "peak / limit torque |", "| --- | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for j, name in enumerate(limits.joint_names):
        pk = phys["joints"][name]
        torque = f"{pk['torque']:.4g} / " if "torque" in pk else ""
        lines.append(
            f"| {name} | {limits.position_low[j]:.4g} | {limits.position_high[j]:.4g} | "
            f"{pk['velocity']:.4g} / {limits.velocity[j]:.4g} | {pk['acceleration']:.4g} / "
            f"{limits.acceleration[j]:.4g} | {torque}{limits.torque[j]:.4g} |"
        )
    units = "units: rad, rad/s, rad/s^2, N m (prismatic joints: m, m/s, m/s^2, N)"
    lines += ["", units]
    if s["geometry"]:
        moved = (
            " (the middle of the limits, moved clear of the floor)" if s["posture_moved"] else ""
        )
        lines += ["", f"Posture{moved}: {', '.join(f'{v:.4g}' for v in s['posture'])}", ""]
        lines += [f"- {line}" for line in s["geometry"]]
    return lines


def _plots(out, model, limits, traj, rnd, info, rate, duration) -> dict[str, Path]:
    """``trajectory.png`` (positions and velocities against the random excitation's, with the
    limits) and ``singular_values.png`` (the base regressor's singular values)."""
    from matplotlib.figure import Figure  # no pyplot: the caller's backend stays as it is

    t = np.arange(int(round(duration * rate))) / rate
    qo, qdo, _ = traj.evaluate_numpy(t)
    qr, qdr, _ = rnd.evaluate_numpy(np.mod(t, rnd.period))
    n = model.n_dof
    fig = Figure(figsize=(11, 1.6 * n + 1))
    axes = fig.subplots(n, 2, sharex=True, squeeze=False)
    for j in range(n):
        ax = axes[j, 0]
        ax.plot(t, qo[:, j], "C0", lw=1.2, label="optimised")
        ax.plot(t, qr[:, j], "C1--", lw=1.0, label="random")
        for v in (limits.position_low[j], limits.position_high[j]):
            ax.axhline(v, color="k", lw=0.8, ls=":")
        ax.set_ylabel(model.joint_names[j], fontsize=7)
        ax = axes[j, 1]
        ax.plot(t, qdo[:, j], "C0", lw=1.2)
        ax.plot(t, qdr[:, j], "C1--", lw=1.0)
        if np.isfinite(limits.velocity[j]):
            for v in (-limits.velocity[j], limits.velocity[j]):
                ax.axhline(v, color="k", lw=0.8, ls=":")
    axes[0, 0].set_title("position (dotted: limits with the margin)")
    axes[0, 1].set_title("velocity (dotted: limits)")
    axes[0, 0].legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out / "trajectory.png", dpi=110)
    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    for key, style in (("optimised", "C0o-"), ("random", "C1s--")):
        sv = info[key]["singular_values"]
        ax.semilogy(np.arange(1, sv.size + 1), sv, style, ms=3,
                    label=f"{key} (cond {info[key]['condition_number']:.3g})")  # fmt: skip
    ax.set_xlabel("index")
    ax.set_ylabel("singular value of Y V / sqrt(N)")
    ax.set_title("base regressor")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "singular_values.png", dpi=110)
    return {"figure": out / "trajectory.png", "singular_values": out / "singular_values.png"}
