"""The error of bad input, shared by every reader and check of a recording."""
from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad user input: an unreadable file, a missing column, a non-numeric value …; ``column`` names the
    column of a bad value (None when the error is not about one column's values)."""

    def __init__(self, message: str, column: str | None = None):
        super().__init__(message)
        self.column = column
