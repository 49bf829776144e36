"""Progress bars for long work (tqdm), off by default in the library, on in scripts."""

from __future__ import annotations

from tqdm import tqdm

__all__ = ["progress_bar"]


def progress_bar(*, total: int | None, desc: str, enabled: bool, unit: str = "it"):
    """A tqdm bar, or a do-nothing bar when ``enabled`` is False.

    Use as a context manager and call ``bar.update(k)``; ``bar.set_postfix(...)`` works too.
    """
    return tqdm(
        total=total, desc=desc, disable=not enabled, unit=unit, leave=False, dynamic_ncols=True
    )
