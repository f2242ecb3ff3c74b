"""Errors a user can fix, reported in one line (see ``cli``).
"""

from __future__ import annotations


class CommandError(ValueError):
    """A failure the user can fix: its message is the one line after ``gpsins CMD:``."""
