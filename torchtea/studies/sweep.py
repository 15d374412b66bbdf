"""Sweeps: a study file whose ``[sweep]`` table lists values of truth and estimator settings (and of the study's
``prior``).

Every combination of the listed values is a sub-study; all of them share the study's seed, so realisation ``i``
of every sub-study draws the same input and noises (common random numbers: the sub-studies differ by their
settings, not by their luck) — unless the sweep changes the truth's length ``n`` or whether it has an input,
which changes what is drawn. ::

    realisations = 200
    seed = 5
    [estimator]
    preset = "paper-example1"
    [sweep.truth]
    order = ["0.2", "0.6"]
    param = [-0.5, -2.0]
    [sweep.estimator.kfo]
    Q0 = [0.1, 0.01]

makes 2 × 2 × 2 = 8 sub-studies named like ``order=0.2,param=-0.5,kfo.Q0=0.1``.
"""
from __future__ import annotations

import copy
import itertools
import re

from .montecarlo import Study, build_study

__all__ = ["SubStudy", "build_sweep", "sweep_axes"]

SWEEPABLE = ("truth", "estimator", "prior")


class SubStudy:
    """One combination of a sweep: its ``name`` (also its run directory), the swept ``values`` (dotted path →
    value, e.g. ``{"truth.order": "0.2"}``), the :class:`Study` and the estimator's preset name."""

    def __init__(self, name: str, values: dict, study: Study, preset: str):
        self.name, self.values, self.study, self.preset = name, values, study, preset

    def hparams(self) -> dict:
        """The swept values as TensorBoard hparams (lists as strings; TensorBoard takes numbers, strings, bools)."""
        return {f"sweep.{k}": v if isinstance(v, (bool, int, float, str)) else str(v) for k, v in self.values.items()}


def sweep_axes(table: dict, source: str = "sweep", *, paths: dict | None = None) -> dict:
    """The ``[sweep]`` table flattened to ``{"truth.order": [values…], "estimator.kfo.Q0": [values…], "prior": […]}``;
    ``paths`` (a dict, filled in) gets each setting's key path, for names with a dot of their own
    (``truth.values."random-walk.sigma"``)."""
    axes = {}
    paths = {} if paths is None else paths

    def walk(node, path):
        for key, value in node.items():
            p = path + (key,)
            if isinstance(value, dict):
                walk(value, p)
            elif isinstance(value, list):
                if not value:
                    raise ValueError(f"{source}: [sweep] {'.'.join(p)} lists no values")
                axes[".".join(p)] = value
                paths[".".join(p)] = p
            else:
                raise ValueError(f"{source}: [sweep] {'.'.join(p)} must be a list of values, got {value!r}")

    bad = set(table) - set(SWEEPABLE)
    if bad:
        raise ValueError(f"{source}: [sweep] can list truth and estimator settings and the prior, not {sorted(bad)}")
    walk(table, ())
    if not axes:
        raise ValueError(f"{source}: the [sweep] table lists no settings")
    return axes


def build_sweep(data: dict, flags: dict | None = None, *, memory=None, source: str = "study") -> list[SubStudy]:
    """The sub-studies of a study table with a ``[sweep]`` table (see the module's docstring), each built by
    :func:`~torchtea.studies.montecarlo.build_study` with ``flags`` on top. A flag that sets a swept truth
    setting is refused (it would make every sub-study the same)."""
    from .montecarlo import TRUTH_FLAGS

    data = dict(data)
    paths: dict = {}
    axes = sweep_axes(data.pop("sweep"), source, paths=paths)
    given = {TRUTH_FLAGS.get(k, k) for k, v in (flags or {}).items() if v is not None}
    clash = sorted(p for p in axes if p.split(".", 1)[0] == "truth" and _truth_key(p) in given)
    if clash:
        raise ValueError(f"{source}: {', '.join(clash)} is swept; leave out its command-line flag")
    if "estimator.preset" in axes and (flags or {}).get("preset"):
        raise ValueError(f"{source}: estimator.preset is swept; leave out --preset")
    if "prior" in axes and (flags or {}).get("prior"):
        raise ValueError(f"{source}: prior is swept; leave out --prior")
    subs, names = [], set()
    for combo in itertools.product(*axes.values()):
        values = dict(zip(axes, combo))
        table = copy.deepcopy(data)
        for path, value in values.items():
            node = table
            *parents, leaf = paths[path]
            for key in parents:
                node = node.setdefault(key, {})
                if not isinstance(node, dict):
                    raise ValueError(f"{source}: [sweep] {path}: {key} is not a table")
            node[leaf] = value
        name = _name(values)
        if name in names:
            raise ValueError(f"{source}: [sweep] lists a combination twice ({name})")
        names.add(name)
        study, preset = build_study(table, flags, memory=memory, source=f"{source} [{name}]")
        subs.append(SubStudy(name, values, study, preset))
    return subs


def _truth_key(path: str) -> str:
    key = path.split(".", 1)[1]
    return "n_steps" if key == "n" else key


def _name(values: dict) -> str:
    """``order=0.2,kfo.Q0=0.1``: each swept setting without its ``truth.``/``estimator.`` prefix, unless two
    settings would then read alike (``truth.memory`` and ``estimator.memory``)."""
    shorts = [p.split(".", 1)[-1] for p in values]
    parts = []
    for (path, value), short in zip(values.items(), shorts):
        label = path if shorts.count(short) > 1 else short
        text = ",".join(map(str, value)) if isinstance(value, list) else str(value)
        parts.append(f"{label}={text}")
    return re.sub(r"[^A-Za-z0-9._=,+-]", "_", ",".join(parts))
