"""Numbers in text lines."""
from __future__ import annotations

import math

__all__ = ["num"]


def num(v, spec: str) -> str:
    """``v`` formatted with ``spec``; ``"n/a"`` for None or a value that is not finite (what a report says of a
    number that was not computed)."""
    return "n/a" if v is None or not math.isfinite(v) else format(v, spec)
