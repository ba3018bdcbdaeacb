"""Exceptions meant for the user: each message says what is wrong and what to do next.

The CLI prints these without a traceback and exits with status 2; anything else is a bug and
keeps its traceback.
"""

from __future__ import annotations

__all__ = ["AesPlannerError"]


class AesPlannerError(Exception):
    """Base class of errors caused by input, files or hardware rather than by a bug."""
