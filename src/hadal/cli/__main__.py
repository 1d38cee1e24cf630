"""``python -m hadal.cli``: the ``hadal`` command."""

from hadal.cli import entry

entry()
