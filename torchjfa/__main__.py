"""``python -m torchjfa``: the same as the ``torchjfa`` command."""

from .cli import entry

entry()
