"""The toolkit's error tree. Public fields, causes chained with `from`."""

from __future__ import annotations


class PlmarlError(Exception):
    """Base of every error the toolkit raises on purpose."""


class UserError(PlmarlError):
    """Something the user gave is wrong (a flag, a file); the message says what to fix."""
