"""JSON that strict parsers accept: a number that is not finite (NaN, ±inf) is written as ``null``.

Python's :func:`json.dumps` writes ``NaN`` and ``Infinity`` by default, which RFC 8259 does not allow and
strict readers (JavaScript's ``JSON.parse``, ``jq``, Go's ``encoding/json``) reject. Every JSON file and
``--json`` line torchtea writes goes through :func:`dumps`, which converts first and then asks the
encoder to refuse anything non-finite that is left (``allow_nan=False``), so a slip is an error, not a
silently invalid file. Readers get ``None`` for "no number": a statistic of an empty set, a settling
time that never came.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

__all__ = ["strict", "dumps", "write"]


def strict(obj):
    """A copy of ``obj`` with every non-finite float replaced by ``None``; NumPy and 0-d torch scalars become
    Python numbers, tuples become lists. Dict keys are kept as they are."""
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    item = getattr(obj, "item", None)  # numpy scalars and 0-d arrays, 0-d tensors
    if callable(item) and getattr(obj, "ndim", 0) == 0:
        return strict(item())
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return strict(tolist())
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def dumps(obj, *, indent: int | None = None) -> str:
    """Strict JSON text of ``obj`` (see the module docstring)."""
    import json

    return json.dumps(strict(obj), indent=indent, allow_nan=False)


def write(path, obj, *, atomic: bool = False) -> Path:
    """Write ``obj`` as indented strict JSON; ``atomic`` writes a temporary file and renames it over ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = dumps(obj, indent=2) + "\n"
    if not atomic:
        path.write_text(text, encoding="utf-8")
        return path
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
    return path
