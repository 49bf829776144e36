"""``torchjfa refine``: the identified model's joint terms refined on MuJoCo rollouts
(`torchjfa.sim.refine`, the ``sysid`` extra), kept where held-out rollouts improve.

    torchjfa refine result/model.npz run1.csv run2.csv --held-out run3.csv --out refined/
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..io import output_folder
from ._common import (
    COMMANDS,
    UsageError,
    add_output,
    add_reading,
    reading,
    written_as,
)

__all__ = ["add_refine", "cmd_refine"]


def add_refine(sub) -> argparse.ArgumentParser:
    """The ``refine`` sub-command's parser (runs `cmd_refine`)."""
    p = sub.add_parser(
        "refine",
        help=COMMANDS["refine"],
        description="Start from the identified model's MJCF export and fit, per joint, MuJoCo's "
        "friction loss, damping and armature (and with --delay one delay between the logged "
        "torque and the joints) to open-loop rollouts on the training logs, with mujoco.sysid; "
        "keep what rollouts on the --held-out logs confirm (per joint, then as a whole). Writes "
        "refined.xml, refinement.json and refinement.md. Needs the sysid extra: "
        'pip install "torchjfa[sysid]".',
    )
    p.add_argument("model", help="model.npz written by identify")
    p.add_argument("logs", nargs="+", metavar="LOG", help="logs to fit the rollouts on")
    p.add_argument(
        "--held-out",
        nargs="+",
        required=True,
        metavar="LOG",
        help="logs that judge the fit (not the identification's held-out part you report on)",
    )
    p.add_argument("--delay", action="store_true", help="also fit a torque delay, s")
    add_output(p, default="refined", what="the refined MJCF and its report")
    add_reading(p)
    p.set_defaults(func=cmd_refine)
    return p


def cmd_refine(args) -> int:
    """Run ``torchjfa refine`` (see `add_refine`)."""
    from ..identification._prepare import identified_model, read_prepared, several
    from ..sim import refine

    ident = identified_model(args.model)
    model, theta, cutoff = ident.model, ident.theta, ident.cutoff_hz
    options = reading(args)

    def prepared(logs):
        return [read_prepared(s, model, options, cutoff)[1] for s in several(logs)]

    parameters = ("frictionloss", "damping", "armature") + (("delay",) if args.delay else ())
    try:
        result = refine(
            model, theta, prepared(args.logs), prepared(args.held_out), parameters=parameters
        )
    except (ImportError, ValueError) as exc:  # the missing extra, logs too short
        raise UsageError(" ".join(str(exc).split())) from None
    out, lines = Path(args.out), result.lines()
    with output_folder(out, **written_as(args, args.model, *args.logs, *args.held_out)) as stage:
        (stage / "refined.xml").write_text(result.mjcf, encoding="utf-8")
        (stage / "refinement.json").write_text(json.dumps(result.summary(), indent=1))
        (stage / "refinement.md").write_text(
            "# Refinement on MuJoCo rollouts\n\n```text\n" + "\n".join(lines) + "\n```\n"
        )
    for line in lines:
        print(line)
    kept = ", ".join(result.accepted) or "nothing (the identified values stay)"
    print(f"kept: {kept}; written: {out / 'refined.xml'}, refinement.json, refinement.md")
    return 0
