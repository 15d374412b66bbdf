"""TEA configs as TOML: load (with an optional base preset) and write next to outputs."""
from __future__ import annotations

import math
import re
from pathlib import Path

try:  # Python ≥ 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib

from ..sensors.io import InputError
from .presets import get_preset
from .settings import TEAConfig

__all__ = ["read_toml", "load_config", "dumps_toml", "write_config"]


def read_toml(path, what: str = "config") -> dict:
    """Parse a TOML file; a missing file or bad syntax is an :class:`InputError` naming the file."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: no such {what} file") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None


def load_config(path) -> TEAConfig:
    """Read a TEA config from TOML.

    A top-level ``preset = "paper-example1"`` picks the base settings (default:
    :class:`TEAConfig` defaults); tables ``[kfx]``, ``[kfo]``, ``[kfw]`` and the
    top-level options override it, e.g.::

        preset = "paper-example2"
        sigma_sum_start = 0
        [kfw]
        delta = 0.0
    """
    path = Path(path)
    data = read_toml(path)
    base = get_preset(data.pop("preset")) if "preset" in data else TEAConfig()
    try:
        return TEAConfig.from_dict(data, base)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from None


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        f = float(v)
        if isinstance(v, int):
            return str(v)
        return repr(f) if math.isfinite(f) else ("nan" if math.isnan(f) else ("inf" if f > 0 else "-inf"))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _key(k) -> str:
    """A TOML key: bare where TOML allows it, else quoted (``"fractional.order"``)."""
    k = str(k)
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else '"' + k.replace("\\", "\\\\").replace('"', '\\"') + '"'


def dumps_toml(data: dict, _prefix: str = "") -> str:
    """Minimal TOML writer for nested dicts of numbers, strings, booleans and lists (sub-dicts become tables)."""
    out = [f"{_key(k)} = {_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for name, table in data.items():
        if isinstance(table, dict):
            header = f"{_prefix}{_key(name)}"
            out.append("")
            out.append(f"[{header}]")
            out.append(dumps_toml(table, header + ".").rstrip("\n"))
    return "\n".join(line for line in out) + "\n"


def write_config(path, config: TEAConfig, extra: dict | None = None) -> Path:
    """Write ``config`` as TOML that :func:`load_config` reads back; ``extra`` (e.g. ``h``, the source)
    goes in as comments above it, since it is context, not a setting."""
    notes = "".join(f"# {k} = {_value(v)}\n" for k, v in (extra or {}).items())
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(notes + dumps_toml(config.to_dict()))
    return path
