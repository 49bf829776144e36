"""The flow's error and warning types."""

from __future__ import annotations

__all__ = ["IdentificationError", "IdentificationWarning"]


class IdentificationError(ValueError):
    """The data or the options cannot give an identification: what is wrong, and what to do.

    (The command line prints it as one line and exits with status 2.)"""


class IdentificationWarning(UserWarning):
    """The identification ran but something in it needs the user's attention."""
