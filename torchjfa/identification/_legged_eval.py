"""`evaluate_legged`: an identified floating-base model judged on legged logs it was not
identified from (``torchjfa evaluate result/model.npz walk.csv``)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from .._util import output_folder
from ..data import edge_seconds
from ..dynamics import FloatingBaseModel
from ._contacts import row_moments
from ._legged import BASE_ROW_LABELS, ROW_TEXT, prepared_log, with_raw_targets
from ._legged_read import check_legged_options, choose_rows, read_legged
from ._options import IdentificationError, Options

__all__ = ["LeggedEvaluation", "evaluate_legged"]


@dataclass(eq=False)
class LeggedEvaluation:
    """What `evaluate_legged` found.

    Attributes:
        model: the `torchjfa.dynamics.FloatingBaseModel`.
        cutoff_hz: the cut-off the logs were prepared at, Hz.
        rows: ``"all"`` or ``"projected"``: which rows the logs give (as `identify_legged`).
        row_labels: the rows' names.
        logs: per log: ``{"log", "samples", "measured", "description", "identified"}``, the
            last three ``(r,)`` RMS per row (N, N m), against the unfiltered torques and
            wrenches.
    """

    model: FloatingBaseModel
    cutoff_hz: float
    rows: str
    row_labels: tuple[str, ...]
    logs: list[dict] = field(default_factory=list)

    def lines(self) -> list[str]:
        """One line per log: the identified model's joint-torque RMS beside the description's."""
        out = []
        for entry in self.logs:
            joints = slice(6, None)
            ident = float(entry["identified"][joints].pow(2).mean().sqrt())
            desc = float(entry["description"][joints].pow(2).mean().sqrt())
            out.append(
                f"{entry['log']}: {entry['samples']} samples, joint rows' RMS {ident:.4g} "
                f"(description {desc:.4g}, {ident / desc:.3g}x); {ROW_TEXT[self.rows]}"
            )
        return out

    def summary(self) -> dict:
        """The numbers, as JSON-ready values."""
        return {
            "cutoff_hz": self.cutoff_hz,
            "rows": self.rows,
            "row_labels": list(self.row_labels),
            "logs": [
                {k: (v.tolist() if isinstance(v, torch.Tensor) else v) for k, v in e.items()}
                for e in self.logs
            ],
        }

    def write(self, out_dir, *, overwrite: bool = False, inputs=(), command: str = "") -> dict:
        """Write ``evaluation.json`` into ``out_dir`` as one unit; returns its path."""
        out = Path(out_dir)
        with output_folder(out, overwrite=overwrite, inputs=inputs, command=command) as stage:
            text = json.dumps(self.summary(), indent=1)
            (stage / "evaluation.json").write_text(text, encoding="utf-8")
        return {"json": out / "evaluation.json"}


def evaluate_legged(identified, logs, options: Options | None = None, *, cutoff_hz=None):
    """Judge an identified floating-base model on legged logs.

    Each log is read as `identify_legged` reads it, prepared whole at the model's cut-off (or
    ``cutoff_hz``), the filter's reach dropped at its ends, and its rows (every row with the
    measured contact wrenches, or with contact flags only the projected rows) compared with
    the model's and the description's predictions.

    Args:
        identified: a `torchjfa.io.IdentifiedModel` of a `FloatingBaseModel` (``model.npz``
            of a floating-base identification, read with `torchjfa.io.read_identified`).
        logs: legged logs (paths or `torchjfa.data.LeggedLog` s).
        options: the reading options (`Options.time_scale`, `Options.flat_contacts`, and
            `Options.imu_frame`: the logs' IMU is used only where its frame is named).
        cutoff_hz: prepare at this cut-off, Hz (default: the model's).

    Raises:
        IdentificationError: on a model that is not a floating-base one, or logs that do not
            match it (as `identify_legged`).
    """
    model, theta = identified.model, identified.theta.to(torch.float64)
    if not isinstance(model, FloatingBaseModel):
        raise IdentificationError("the model file holds a fixed-base robot: evaluate joint logs")
    options = Options() if options is None else options
    check_legged_options(options)
    cutoff = float(cutoff_hz or identified.cutoff_hz)
    sources = list(logs) if isinstance(logs, list | tuple) else [logs]
    raws = [read_legged(s, model, options) for s in sources]
    if options.imu_frame is None:  # no frame named: the base's motion from the pose
        raws = [replace(r, imu={}) for r in raws]
    rows = "all" if choose_rows(raws, options) == "all" else "projected"
    flat = tuple(options.flat_contacts) if rows == "projected" else ()
    edge = edge_seconds(cutoff)
    result = LeggedEvaluation(model, cutoff, rows, BASE_ROW_LABELS + model.joint_names)
    for source, raw in zip(sources, raws, strict=True):
        keep = (raw.t >= raw.t[0] + edge) & (raw.t <= raw.t[-1] - edge)
        if not keep.any():
            raise IdentificationError(f"{source}: shorter than the filter's reach ({edge:.2g} s)")
        prepared = prepared_log(raw, cutoff).select(keep)
        judged = with_raw_targets(prepared, raw.select(keep))
        m = row_moments(model, judged, rows=rows, flat=flat)
        result.logs.append({
            "log": os.fspath(source) if isinstance(source, str | os.PathLike) else "log",
            "samples": m.n_samples,
            "measured": m.target_rms(),
            "description": m.rms(model.description_theta),
            "identified": m.rms(theta),
        })  # fmt: skip
    return result
