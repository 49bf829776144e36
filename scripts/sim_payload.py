"""Payload identification in simulation: known bodies on the flange of a Panda and a UR5-like arm,
found by `torchjfa.identify_payload` with an identified (not the true) robot model.

    python scripts/sim_payload.py             # both robots, six payloads, seeds 0-2 (minutes)
    python scripts/sim_payload.py --smoke     # one period, one payload per robot, one seed
    python scripts/sim_payload.py --robots panda --seeds 5
    python scripts/sim_payload.py --seeds 1 --noise-scale 0   # what the noise costs
    python scripts/sim_payload.py --write-docs   # also into docs/benchmarks.md

Per robot (the shipped ``panda_arm``, payload on ``panda_link8``; example-robot-data's
``ur_description/urdf/ur5_robot.urdf``, payload on ``ee_link``, skipped with a message when
example-robot-data is not installed):

1. The excitation: `torchjfa.excitation.optimize_excitation` on the robot's description (its
   limits from `limits_from_model`, 10 s period, 5 harmonics of 0.1 Hz, modest optimiser
   settings, ``EXCITATION``), written to ``OUT/excitation_<robot>.npz`` and read back on the
   next run with the same settings. Should the optimisation fail, the library's random sum of
   sinusoids (`torchjfa.sim.random_trajectory`, same period and highest harmonic, inside the
   joint ranges and velocity limits) is used instead; the output says which excitation ran.
2. The simulated robot: the description compiled for MuJoCo (`torchjfa.sim.load_description`)
   with joint damping and dry friction (MuJoCo's ``frictionloss``; each robot's ``effects`` in
   ``ROBOTS``), tracking ``--seconds`` (60 s: six periods) of the excitation at 500 Hz
   (`torchjfa.sim.generate_log`, computed-torque tracking) with sensor noise of the size real
   robots show (each robot's ``noise`` in ``ROBOTS``: the Panda's torque noise from the
   high-frequency content of a real Panda's link-side torque sensors, 0.04-0.4 N m; the UR5's
   from a real UR10e's motor-current torques scaled by the ratio of the two arms' rated
   torques, 0.13-1 N m; white at every sample; velocities from the noisy velocity sensor,
   accelerations differentiated). ``--noise-scale`` multiplies the noise: at 0 what is left
   is the identified robot model's error.
3. The payloads (``PAYLOADS``): solid boxes and cylinders of 0.5, 2 and 5 kg with their centres
   of mass several cm off the flange and their axes turned. Each is attached to the flange
   link as an extra URDF link on a fixed joint, so MuJoCo lumps its true inertial into the
   body that carries the flange. Masses above a robot's rating (the Panda's is 3 kg) are
   simulated as they are (the simulator does not limit the torques); the ``effort`` column is
   the loaded run's peak torque over the description's effort limit, worst joint.
4. Per seed: an unloaded run identifies the robot (`torchjfa.identify`, the defaults), whose
   model file is written to ``OUT/<robot>/seed<k>/``; each payload's loaded run (its own noise)
   is then given to `torchjfa.identify_payload` twice: with the unloaded run as its twin
   (``pair``: robot and payload fitted together on both runs) and against the identified
   robot alone (``robot``). Both hold out the last part of the loaded run (the defaults).

Printed per robot and payload and seed, for both ways: the mass error (%), the distance of the
found centre of mass from the true one (mm), the errors of the inertia's principal moments about
the centre of mass (eigenvalues in ascending order, %); then, per way, whether the criteria
hold over every row: mass within 1 %, centre of mass within 5 mm, principal moments within
20 % for payloads of 2 kg and more. The seeds change the sensor noise; the excitation is the
same for every seed.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import _benchmarks_page as page
import numpy as np

import torchjfa
from torchjfa.identification import IdentificationWarning
from torchjfa.sim import SensorNoise, SinusoidTrajectory, generate_log, load_description

RATE = 500.0  # control and sampling rate, Hz
PERIOD = 10.0  # excitation period, s
HARMONICS = 5
#: the excitation's optimiser settings (full run, smoke run)
EXCITATION = {
    "full": {"n_starts": 2, "max_iter": 30, "polish_iter": 50, "polish_starts": 1, "seed": 0},
    "smoke": {"n_starts": 1, "max_iter": 5, "polish_iter": 5, "polish_starts": 1, "n_grid": 50,
              "rate": 20.0, "seed": 0},
}  # fmt: skip
#: the criteria (mass %, centre of mass mm, principal moments %, the mass from which the
#: moments are judged, kg)
MASS_PCT, COM_MM, MOMENT_PCT, MOMENT_FROM_KG = 1.0, 5.0, 20.0, 2.0
WAYS = ("pair", "robot")


@dataclass(frozen=True)
class Robot:
    """A simulated robot: its description, flange link, sensor noise and joint effects."""

    name: str
    description: str  # a shipped robot's name or an example-robot-data path
    link: str
    noise: SensorNoise
    effects: dict

    def path(self) -> str:
        if self.description in torchjfa.robots.available():
            return str(torchjfa.robots.path(self.description))
        return torchjfa.robots.example_robot_data_path(self.description)


ROBOTS = {
    "panda": Robot(
        "panda", "panda_arm", "panda_link8",
        SensorNoise(2e-4, 5e-3, (0.3, 0.4, 0.25, 0.35, 0.1, 0.1, 0.04)),
        {"damping": (0.5, 0.5, 0.5, 0.5, 0.2, 0.2, 0.2),
         "frictionloss": (0.4, 0.4, 0.3, 0.4, 0.2, 0.2, 0.15)},
    ),
    "ur5": Robot(
        "ur5", "ur_description/urdf/ur5_robot.urdf", "ee_link",
        SensorNoise(2e-4, 2e-3, (0.8, 1.0, 0.5, 0.13, 0.18, 0.15)),
        {"damping": (2.0, 2.0, 1.5, 0.4, 0.4, 0.4),
         "frictionloss": (3.0, 3.0, 2.0, 0.6, 0.6, 0.6)},
    ),
}  # fmt: skip


@dataclass(frozen=True)
class Body:
    """A solid box (``size``: edge lengths along its x, y, z, m) or cylinder (``size``:
    radius and length along its z, m) of uniform density, its centre of mass at ``com`` in the
    flange link's frame (m), its axes turned by ``rpy`` (URDF roll, pitch, yaw, rad)."""

    name: str
    mass: float
    shape: str
    size: tuple[float, ...]
    com: tuple[float, float, float]
    rpy: tuple[float, float, float]

    def inertia(self) -> np.ndarray:
        """``(3, 3)`` about the centre of mass, in the link's axes, kg m^2."""
        m = self.mass
        if self.shape == "box":
            a, b, c = self.size
            d = m / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        else:
            r, h = self.size
            side = m * (3.0 * r * r + h * h) / 12.0
            d = np.array([side, side, 0.5 * m * r * r])
        R = _rotation(self.rpy)
        return R @ np.diag(d) @ R.T


def _rotation(rpy) -> np.ndarray:
    """URDF's roll-pitch-yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


PAYLOADS = (
    Body("box 0.5 kg", 0.5, "box", (0.10, 0.08, 0.05), (0.00, 0.02, 0.04), (0.0, 0.0, 0.0)),
    Body("cylinder 0.5 kg", 0.5, "cylinder", (0.03, 0.15), (0.03, 0.00, 0.06), (0.0, 1.5708, 0.0)),
    Body("box 2 kg", 2.0, "box", (0.20, 0.10, 0.06), (0.04, -0.03, 0.07), (0.2, 0.1, 0.5)),
    Body("cylinder 2 kg", 2.0, "cylinder", (0.045, 0.20), (-0.03, 0.04, 0.10), (0.3, 0.0, 0.0)),
    Body("box 5 kg", 5.0, "box", (0.25, 0.15, 0.08), (0.05, 0.03, 0.08), (0.0, 0.3, -0.4)),
    Body("cylinder 5 kg", 5.0, "cylinder", (0.06, 0.25), (0.0, -0.05, 0.12), (1.5708, 0.0, 0.3)),
)
#: the one payload per robot of ``--smoke``
SMOKE_PAYLOADS = {"panda": "box 5 kg", "ur5": "cylinder 5 kg"}


# ------------------------------------------------------------------------------ simulation
def loaded_urdf(robot_urdf: str, link: str, body: Body, path: Path) -> Path:
    """The robot's URDF with ``body`` as a link ``sim_payload`` fixed to ``link``, at ``path``."""
    root = ET.parse(robot_urdf).getroot()
    if link not in {e.get("name") for e in root.findall("link")}:
        raise SystemExit(f"{robot_urdf} has no link {link!r}")
    I = body.inertia()  # noqa: E741
    new = ET.SubElement(root, "link", name="sim_payload")
    inertial = ET.SubElement(new, "inertial")
    ET.SubElement(inertial, "origin", xyz=" ".join(repr(float(x)) for x in body.com), rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=repr(float(body.mass)))
    six = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}
    ET.SubElement(inertial, "inertia", **{k: repr(float(I[i, j])) for k, (i, j) in six.items()})
    joint = ET.SubElement(root, "joint", name="sim_payload_fixed", type="fixed")
    ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(joint, "parent", link=link)
    ET.SubElement(joint, "child", link="sim_payload")
    path.write_text(ET.tostring(root, encoding="unicode"))
    return path


def _reordered(traj: SinusoidTrajectory, names, order) -> SinusoidTrajectory:
    """``traj`` (joints ``names``) in the joint order ``order``."""
    perm = [list(names).index(j) for j in order]
    return SinusoidTrajectory(
        traj.base_frequency,
        traj.offset[perm],
        traj.amplitude[perm],
        traj.harmonic[perm],
        traj.phase[perm],
    )


def excitation(robot: Robot, description, out: Path, *, smoke: bool) -> tuple:
    """``(SinusoidTrajectory in MuJoCo's joint order, what it is)``: the optimised excitation,
    read from ``out`` when a run with the same settings wrote it, else optimised and written;
    the random one if the optimisation fails."""
    settings = {
        "period": PERIOD,
        "harmonics": HARMONICS,
        **EXCITATION["smoke" if smoke else "full"],
    }
    key = json.dumps(settings, sort_keys=True)
    cache = out / f"excitation_{robot.name}{'_smoke' if smoke else ''}.npz"
    try:
        from torchjfa.dynamics import RigidBodyModel
        from torchjfa.excitation import FourierTrajectory, limits_from_model, optimize_excitation

        traj = None
        if cache.is_file():
            with np.load(cache, allow_pickle=False) as z:
                same = "sim_payload_settings" in z.files and str(z["sim_payload_settings"]) == key
            if same:
                traj, how = FourierTrajectory.load(cache), f"optimised (read back from {cache})"
        if traj is None:
            model = RigidBodyModel.from_urdf(robot.path())
            options = dict(settings)
            options.pop("period")
            res = optimize_excitation(
                model,
                limits_from_model(model),
                duration=PERIOD,
                base_frequency=1.0 / PERIOD,
                **options,
            )
            traj = res.trajectory
            traj.save(cache, sim_payload_settings=np.array(key))
            how = (
                f"optimised in {res.seconds:.0f} s (condition number {res.condition_number:.3g}"
                f"), written to {cache}"
            )
        sin = _reordered(traj.to_sinusoid(), traj.joint_names, description.joint_names)
        return sin, how
    except Exception as exc:  # the optimiser's failure is reported, the check goes on
        from torchjfa.sim import random_trajectory

        finite = np.where(np.isfinite(description.velocity_limit), description.velocity_limit, 2.0)
        sin = random_trajectory(
            description.model,
            base_frequency=1.0 / PERIOD,
            max_harmonic=HARMONICS,
            seed=0,
            velocity_limit=finite,
        )
        reason = " ".join(str(exc).split())[:200]
        return (
            sin,
            f"random sum of sinusoids (the optimisation failed: {type(exc).__name__}: {reason})",
        )


def _errors(found, body: Body) -> dict:
    """Mass error %, centre-of-mass distance mm, principal-moment errors % (ascending)."""
    true_moments = np.linalg.eigvalsh(body.inertia())
    moments = np.linalg.eigvalsh(np.asarray(found.inertia, dtype=np.float64))
    com = np.asarray(found.com, dtype=np.float64)
    return {
        "mass": float(found.mass),
        "mass_std": float(found.std[0]),
        "mass_err_pct": 100.0 * (float(found.mass) / body.mass - 1.0),
        "com_err_mm": 1000.0 * float(np.linalg.norm(com - np.asarray(body.com))),
        "moment_err_pct": (100.0 * (moments / true_moments - 1.0)).tolist(),
        "moment_err": (moments - true_moments).tolist(),
        "com": com.tolist(),
        "moments": moments.tolist(),
        "true_moments": true_moments.tolist(),
    }


def run_robot(
    robot: Robot,
    payloads,
    seeds,
    *,
    seconds: float,
    out: Path,
    smoke: bool,
    noise_scale: float = 1.0,
    stream=sys.stdout,
) -> dict:
    """The rows of one robot (see the module); ``noise_scale`` multiplies its sensor noise."""
    from torchjfa.identification import identify_payload

    try:
        urdf = robot.path()
    except (ModuleNotFoundError, FileNotFoundError) as exc:
        msg = f"{robot.name}: skipped ({' '.join(str(exc).split())})"
        print(msg, file=stream)
        return {"skipped": msg, "rows": []}
    folder = out / robot.name
    folder.mkdir(parents=True, exist_ok=True)
    free = load_description(urdf, effects=robot.effects, name=robot.name)
    traj, how = excitation(robot, free, out, smoke=smoke)
    n_samples = int(round(seconds * RATE))
    per = int(round(traj.period * RATE))
    if abs(traj.period * RATE - per) > 1e-9 * per:
        raise SystemExit(f"the excitation's period {traj.period} s is no whole number of samples")
    loaded = {
        b.name: load_description(
            loaded_urdf(urdf, robot.link, b, folder / f"loaded_{b.name.replace(' ', '_')}.urdf"),
            effects=robot.effects, name=robot.name,
        )
        for b in payloads
    }  # fmt: skip
    print(
        f"\n{robot.name}: {urdf}, payload on {robot.link}; {seconds:g} s per run at {RATE:g} Hz "
        f"({n_samples / per:g} periods of {traj.period:g} s); excitation: {how}",
        file=stream,
    )
    effort = free.effort_limit
    noise = robot.noise.scaled(noise_scale)
    if noise_scale != 1.0:
        print(f"  sensor noise x {noise_scale:g}", file=stream)

    def peak(log) -> float:
        return float((log.tau_true.abs().numpy() / effort).max())

    rows, seed_info = [], []
    for seed in seeds:
        started = time.perf_counter()
        unloaded = generate_log(
            free.model,
            trajectory=traj,
            n_samples=n_samples,
            control_rate=RATE,
            noise=noise,
            seed=seed,
            name=robot.name,
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentificationWarning)
            ident = torchjfa.identify(urdf, unloaded)
        model_file = ident.write(folder / f"seed{seed}", plots=False)["model"]
        info = {
            "seed": seed,
            "nmse": float(ident.validation_fit.mean_nmse),
            "consistent": bool(ident.report.consistency.ok),
            "cutoff_hz": float(ident.data.cutoff_hz),
            "effort": peak(unloaded),
        }
        seed_info.append(info)
        for k, body in enumerate(payloads):
            log = generate_log(
                loaded[body.name].model,
                trajectory=traj,
                n_samples=n_samples,
                control_rate=RATE,
                noise=noise,
                seed=1000 * (seed + 1) + k,
                name=robot.name,
            )
            row = {
                "robot": robot.name,
                "payload": body.name,
                "true_mass": body.mass,
                "seed": seed,
                "effort": peak(log),
            }
            for way, twin in (("pair", [unloaded]), ("robot", None)):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", IdentificationWarning)
                    found = identify_payload(model_file, log, link=robot.link, unloaded=twin)
                row[way] = _errors(found, body)
            rows.append(row)
        info["seconds"] = time.perf_counter() - started
        print(
            f"  seed {seed}: robot identified from the unloaded run (cut-off "
            f"{info['cutoff_hz']:g} Hz, held-out torque nMSE {info['nmse']:.3g}, physically "
            f"consistent: {'yes' if info['consistent'] else 'NO'}; unloaded peak torque "
            f"{info['effort']:.2f} of the effort limit); {info['seconds']:.0f} s",
            file=stream,
        )
    print_table(rows, stream)
    return {"rows": rows, "excitation": how, "seeds": seed_info, "link": robot.link}


# ------------------------------------------------------------------------------ table
def _moments(values) -> str:
    return "/".join(f"{v:+.0f}" for v in values)


def print_table(rows: list[dict], stream=sys.stdout) -> None:
    head = f"{'payload':<16}{'seed':>5}{'effort':>7}"
    for way in WAYS:
        head += f" | {way + ': mass %':>14}{'COM mm':>8}{'moments %':>18}"
    print(head, file=stream)
    for r in rows:
        line = f"{r['payload']:<16}{r['seed']:>5}{r['effort']:>7.2f}"
        for way in WAYS:
            e = r[way]
            line += (
                f" | {e['mass_err_pct']:>+14.3f}{e['com_err_mm']:>8.2f}"
                f" {_moments(e['moment_err_pct']):>17}"
            )
        print(line, file=stream)


def verdicts(rows: list[dict]) -> dict:
    """Per way: the worst value of each criterion over the rows and whether it holds."""
    out = {}
    for way in WAYS:
        mass = max((abs(r[way]["mass_err_pct"]) for r in rows), default=math.nan)
        com = max((r[way]["com_err_mm"] for r in rows), default=math.nan)
        heavy = [r for r in rows if r["true_mass"] >= MOMENT_FROM_KG]
        moment = max((abs(x) for r in heavy for x in r[way]["moment_err_pct"]), default=math.nan)
        absolute = max((abs(x) for r in heavy for x in r[way]["moment_err"]), default=math.nan)
        out[way] = {
            "mass_pct": mass, "mass": mass <= MASS_PCT,
            "com_mm": com, "com": com <= COM_MM,
            "moment_pct": moment, "moment": moment <= MOMENT_PCT, "moment_kgm2": absolute,
        }  # fmt: skip
    return out


def print_verdicts(v: dict, label: str, stream=sys.stdout) -> None:
    def yes(ok):
        return "holds" if ok else "FAILS"

    criteria = (
        ("mass", "mass_pct", f"mass within {MASS_PCT:g} %", "%"),
        ("com", "com_mm", f"centre of mass within {COM_MM:g} mm", "mm"),
        (
            "moment",
            "moment_pct",
            f"principal moments within {MOMENT_PCT:g} % (payloads of {MOMENT_FROM_KG:g} kg and more)",
            "%",
        ),
    )
    for key, worst, text, unit in criteria:
        parts = []
        for way in WAYS:
            extra = f", {v[way]['moment_kgm2']:.2g} kg m^2" if key == "moment" else ""
            parts.append(f"{way} {yes(v[way][key])} (worst {v[way][worst]:.3g} {unit}{extra})")
        print(f"{label}: {text}: " + ", ".join(parts), file=stream)


# ------------------------------------------------------------------------------ run
def run(
    robots=("panda", "ur5"),
    seeds=(0, 1, 2),
    *,
    seconds: float = 60.0,
    out=None,
    smoke: bool = False,
    noise_scale: float = 1.0,
    stream=sys.stdout,
) -> dict:
    """Every robot's rows and the verdicts (see the module); ``out``: the folder for the
    excitations and identified models (default: a temporary one)."""
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) if out is None else Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        results = {
            name: run_robot(
                ROBOTS[name],
                [b for b in PAYLOADS if not smoke or b.name == SMOKE_PAYLOADS[name]],
                seeds,
                seconds=seconds,
                out=folder,
                smoke=smoke,
                noise_scale=noise_scale,
                stream=stream,
            )
            for name in robots
        }
    every = [r for res in results.values() for r in res["rows"]]
    print("", file=stream)
    per_robot = {}
    for name, res in results.items():
        if res["rows"]:
            per_robot[name] = verdicts(res["rows"])
            print_verdicts(per_robot[name], name, stream)
    overall = verdicts(every)
    if every:
        print_verdicts(overall, "all rows", stream)
    print(f"{len(every)} rows in {time.perf_counter() - started:.0f} s", file=stream)
    return {"robots": results, "verdicts": per_robot, "overall": overall}


def parser() -> argparse.ArgumentParser:
    """The command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="panda,ur5", help="comma-separated: panda, ur5")
    ap.add_argument("--seeds", type=int, default=3, help="noise seeds 0..N-1")
    ap.add_argument("--seconds", type=float, default=60.0, help="length of every run, s")
    ap.add_argument(
        "--out",
        type=Path,
        default=Path("results/sim_payload"),
        help="folder for the excitations and the identified models",
    )
    ap.add_argument(
        "--noise-scale",
        type=float,
        default=1.0,
        help="multiply every sensor noise (0: none), to see what the noise costs",
    )
    ap.add_argument(
        "--smoke",
        action="store_true",
        help="one seed, one period, one payload per robot, a quick excitation",
    )
    return page.add_option(ap)


def main(argv=None) -> dict:
    ap = parser()
    args = ap.parse_args(argv)
    robots = tuple(r for r in args.robots.split(",") if r)
    unknown = sorted(set(robots) - set(ROBOTS))
    if unknown:
        ap.error(f"unknown robots {unknown}; choose from {sorted(ROBOTS)}")
    if args.smoke:
        args.seeds, args.seconds = 1, PERIOD
    with page.recording("sim_payload", "sim_payload", args.write_docs, argv, smoke=args.smoke):
        return run(
            robots,
            tuple(range(args.seeds)),
            seconds=args.seconds,
            out=args.out,
            smoke=args.smoke,
            noise_scale=args.noise_scale,
            stream=sys.stdout,
        )


if __name__ == "__main__":
    main()
    sys.exit(0)
