"""Does an excitation designed for the payload alone shorten the run a payload needs? A simulated
Panda with a 2 kg box on its flange, found against an identified robot model.

    python scripts/sim_payload_excitation.py            # 3 seeds, runs of 10, 20 and 60 s
    python scripts/sim_payload_excitation.py --smoke    # one seed, one short run: a check
    python scripts/sim_payload_excitation.py --write-docs   # also into docs/benchmarks.md

The setup is `scripts/sim_payload.py`'s (the shipped ``panda_arm`` in MuJoCo with joint damping
and dry friction, sensor noise of a real Panda's size, 500 Hz, the robot identified with the
defaults from a 60 s unloaded run of the robot's own optimised excitation). The loaded runs
follow either

* the robot's excitation (`torchjfa.excitation.optimize_excitation` on the robot's
  parameters, what `torchjfa excite ROBOT` designs), or
* the payload's (``optimize_excitation(..., payload="panda_link8")``, what ``torchjfa excite
  ROBOT --payload LINK`` designs: the criterion on the payload's 10 parameters alone),

both a 10 s period of 5 harmonics with the same optimiser settings, for ``--seconds`` (10, 20
and 60 s by default). `torchjfa.identify_payload` finds the payload from each loaded run against
the identified robot (no unloaded twin: the run a user makes after mounting a payload on an
identified robot). Printed per excitation and length: the mass error (%), the centre of mass's
distance from the truth (mm) and the largest error of the three principal moments (%), the
mean and the worst over the seeds, and the mean jackknife spread of the mass.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

import torchjfa
from torchjfa.identification import IdentificationWarning, identify_payload

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _benchmarks_page as page  # noqa: E402
import sim_payload as sp  # noqa: E402

PAYLOAD = next(b for b in sp.PAYLOADS if b.mass == 2.0 and b.shape == "box")
SECONDS = (10.0, 20.0, 60.0)
SEEDS = (0, 1, 2)


def payload_excitation(robot, description, out: Path, *, smoke: bool):
    """The payload's optimised excitation in MuJoCo's joint order (cached in ``out``)."""
    from torchjfa.dynamics import RigidBodyModel
    from torchjfa.excitation import FourierTrajectory, limits_from_model, optimize_excitation

    cache = out / f"payload_excitation_{robot.name}{'_smoke' if smoke else ''}.npz"
    if cache.is_file():
        traj = FourierTrajectory.load(cache)
    else:
        model = RigidBodyModel.from_urdf(robot.path())
        options = dict(sp.EXCITATION["smoke" if smoke else "full"])
        res = optimize_excitation(
            model, limits_from_model(model), duration=sp.PERIOD, base_frequency=1.0 / sp.PERIOD,
            harmonics=sp.HARMONICS, payload=robot.link, **options,
        )  # fmt: skip
        traj = res.trajectory
        traj.save(cache)
    return sp._reordered(traj.to_sinusoid(), traj.joint_names, description.joint_names)


def run(out: Path, *, seconds=SECONDS, seeds=SEEDS, smoke: bool = False, stream=sys.stdout):
    """The table of the module; returns its rows."""
    from torchjfa.sim import generate_log, load_description

    robot = sp.ROBOTS["panda"]
    out.mkdir(parents=True, exist_ok=True)
    urdf = robot.path()
    free = load_description(urdf, effects=robot.effects, name=robot.name)
    loaded = load_description(
        sp.loaded_urdf(urdf, robot.link, PAYLOAD, out / "loaded.urdf"),
        effects=robot.effects, name=robot.name,
    )  # fmt: skip
    trajectories = {
        "robot": sp.excitation(robot, free, out, smoke=smoke)[0],
        "payload": payload_excitation(robot, free, out, smoke=smoke),
    }
    rows = []
    for seed in seeds:
        unloaded = generate_log(
            free.model, trajectory=trajectories["robot"], n_samples=int(60 * sp.RATE),
            control_rate=sp.RATE, noise=robot.noise, seed=seed, name=robot.name,
        )  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentificationWarning)
            ident = torchjfa.identify(urdf, unloaded)
        model_file = ident.write(out / f"seed{seed}", plots=False)["model"]
        for name, traj in trajectories.items():
            for s in seconds:
                log = generate_log(
                    loaded.model, trajectory=traj, n_samples=int(round(s * sp.RATE)),
                    control_rate=sp.RATE, noise=robot.noise, seed=1000 + seed, name=robot.name,
                )  # fmt: skip
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", IdentificationWarning)
                    found = identify_payload(model_file, log, link=robot.link)
                rows.append({"excitation": name, "seconds": s, "seed": seed,
                             **sp._errors(found, PAYLOAD)})  # fmt: skip
    print(f"{PAYLOAD.name} on the simulated Panda's {robot.link}, against the identified robot;"
          f" mean (worst) over seeds {list(seeds)}:", file=stream)  # fmt: skip
    print(f"{'excitation':<10} {'s':>4} {'mass %':>13} {'com mm':>13} {'moments %':>13} "
          f"{'mass spread':>11}", file=stream)  # fmt: skip

    def both(values) -> str:
        return f"{np.mean(values):5.2f} ({max(values):5.2f})"

    for name in trajectories:
        for s in seconds:
            sel = [r for r in rows if r["excitation"] == name and r["seconds"] == s]
            mass = both([abs(r["mass_err_pct"]) for r in sel])
            com = both([r["com_err_mm"] for r in sel])
            moments = both([max(abs(e) for e in r["moment_err_pct"]) for r in sel])
            spread = float(np.mean([r["mass_std"] for r in sel]))
            print(f"{name:<10} {s:4g} {mass:>13} {com:>13} {moments:>13} {spread:11.3g}",
                  file=stream)  # fmt: skip
    return rows


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="sim_payload_excitation", help="working folder")
    p.add_argument("--smoke", action="store_true", help="one seed, one 4 s run: a check")
    return page.add_option(p)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    with page.recording("sim_payload_excitation", "sim_payload_excitation", args.write_docs,
                        argv, smoke=args.smoke):  # fmt: skip
        if args.smoke:
            run(Path(args.out), seconds=(4.0,), seeds=(0,), smoke=True)
        else:
            run(Path(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
