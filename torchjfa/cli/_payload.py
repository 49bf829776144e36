"""``torchjfa payload``: a payload fixed to a link (`torchjfa.identification.identify_payload`),
or the drive gains from a payload of known mass (`torchjfa.identification.identify_drive_gains`).

    torchjfa payload result/model.npz loaded.csv --link tool0 --out payload/
    torchjfa payload result/model.npz loaded.csv --unloaded unloaded.csv --link tool0 --mass 2.6
"""

from __future__ import annotations

import argparse
import json
import sys
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

__all__ = ["add_payload", "cmd_payload"]

#: the `torchjfa.identification.Options` fields the command takes besides the reading ones
FIT_OPTIONS = ("estimator", "estimator_options", "weighting", "jackknife")


def add_payload(sub) -> argparse.ArgumentParser:
    """The ``payload`` sub-command's parser (runs `cmd_payload`)."""
    p = sub.add_parser(
        "payload",
        help=COMMANDS["payload"],
        description="The mass, centre of mass and inertia of a rigid body fixed to a link, from "
        "logs with it mounted and the identified robot (model.npz), or from loaded and "
        "unloaded runs together (--unloaded: the robot's parameters are fitted again, so what "
        "its model gets wrong cancels); physically consistent; payload.json in --out.",
    )
    p.add_argument("model", help="model.npz written by identify")
    p.add_argument("loaded", nargs="+", metavar="LOG", help="logs with the payload mounted")
    p.add_argument("--link", required=True, help="the frame the payload is fixed to")
    p.add_argument("--unloaded", nargs="+", default=None, metavar="LOG", help="logs without it")
    p.add_argument(
        "--mass",
        type=float,
        default=None,
        metavar="KG",
        help="the payload's known mass: identify the per-joint drive gains (N m/A; torque scales "
        "for torque logs) instead, with the robot fitted again; needs --unloaded; the logs are "
        "read with --drive-gains as the nominal gains; writes drive_gains.json",
    )
    p.add_argument(
        "--bounds",
        default=None,
        metavar="REGION",
        help="the region of the link's frame the payload lies in, metres: sphere:R (about the "
        "link's origin), sphere:X,Y,Z,R or box:XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX",
    )
    add_output(p, default="payload", what="the payload or the drive gains, and the description")
    add_reading(p, *FIT_OPTIONS)
    p.set_defaults(func=cmd_payload)
    return p


def cmd_payload(args) -> int:
    """Run ``torchjfa payload`` (see `add_payload`)."""
    from ..identification import identify_payload
    from ..identification._payload import write_with_payload

    if args.mass is not None:
        return _drive_gains(args)
    payload = identify_payload(
        args.model,
        args.loaded,
        link=args.link,
        unloaded=args.unloaded,
        options=reading(args, *FIT_OPTIONS),
        bounds=args.bounds,
    )
    out, described = Path(args.out), None
    with _folder(args) as stage:
        (stage / "payload.json").write_text(json.dumps(payload.summary(), indent=1))
        (stage / "payload.md").write_text(payload.markdown())
        try:
            described = out / write_with_payload(args.model, payload, stage).name
        except (UsageError, ValueError) as exc:
            print(f"warning: the description with the payload was not written: {exc}",
                  file=sys.stderr)  # fmt: skip
    print(payload.markdown(brief=True))
    print(f"written: {out / 'payload.json'}, {out / 'payload.md'}"
          + (f", {described}" if described is not None else ""))  # fmt: skip
    return 0


def _folder(args):
    """``--out`` written as one unit (`torchjfa.io.output_folder`)."""
    return output_folder(
        args.out, **written_as(args, args.model, *args.loaded, *(args.unloaded or ()))
    )


def _drive_gains(args) -> int:
    """``torchjfa payload ... --mass KG --unloaded LOG``: the drive gains (drive_gains.json)."""
    from ..identification import identify_drive_gains

    if not args.unloaded:
        raise UsageError("--mass identifies the drive gains and needs --unloaded runs too")
    found = identify_drive_gains(
        args.model, args.loaded, args.unloaded, link=args.link, mass=args.mass,
        options=reading(args, *FIT_OPTIONS),
    )  # fmt: skip
    out = Path(args.out)
    with _folder(args) as stage:
        (stage / "drive_gains.json").write_text(json.dumps(found.summary(), indent=1))
    print(f"drive gains from a {args.mass:g} kg payload on {args.link} (spreads: jackknife):")
    print(found.table())
    gains = ",".join(f"{g:.6g}" for g in found.gains.tolist())
    print(f"read logs with them: --drive-gains {gains}; written: {out / 'drive_gains.json'}")
    return 0
