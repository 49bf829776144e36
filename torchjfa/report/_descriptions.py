"""The identified robot written back into its description, beside a report: ``identified.xml``
(MJCF) and, for a robot read from a URDF, ``identified.urdf``."""

from __future__ import annotations

from pathlib import Path

__all__ = ["write_descriptions"]


def write_descriptions(model, theta, out: Path, *, urdf: bool) -> tuple[dict[str, Path], str]:
    """Write ``identified.xml`` (``model.write_mjcf``) and, with ``urdf``,
    ``identified.urdf`` (``model.write_urdf``) of ``theta`` into the folder ``out``.

    A file that cannot be written (a body MuJoCo refuses, a missing mesh) is left out, and no
    part of it stays in ``out``.

    Returns:
        ``(written, what)``: ``"mjcf"`` and ``"description"`` -> the paths written, and a line
        for the report's settings naming them and why any was not written.
    """
    files = {"mjcf": out / "identified.xml"}
    if urdf:
        files["description"] = out / "identified.urdf"
    written, failed = {}, []
    for key, path in files.items():
        write = model.write_urdf if path.suffix == ".urdf" else model.write_mjcf
        try:
            write(theta, path)
        except (ValueError, OSError) as exc:
            path.unlink(missing_ok=True)
            failed.append(f"{path.name} not written: {exc}")
            continue
        written[key] = path
    return written, "; ".join([f"`{p.name}`" for p in written.values()] + failed)
