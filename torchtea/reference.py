"""The documentation's reference pages, made from the code so they cannot drift from it: every effect of the registry
(its parameters with units, its physics, how ``check`` screens it), every diagnostic, the command line from its own
parser, and the JSON outputs' fields from the ``meaning`` table each file carries. ``docs/gen_pages.py`` writes them
when the site is built; an effect a user registered (:func:`torchtea.effects.register`) is on the page once its module
is imported. Each ``*_page`` function returns one page's Markdown."""
from __future__ import annotations

import argparse
import functools
import inspect
import os
import re
from pathlib import Path

__all__ = ["rst_to_markdown", "sane_lists", "link_design_notes", "effects_page", "diagnostics_page", "cli_page", "json_page", "PAGES"]

_ROLE = re.compile(r":(?:func|class|meth|attr|data|mod|obj|exc):`~?([^`]+)`")


def rst_to_markdown(text: str | None) -> str:
    """A docstring in the package's reStructuredText habits as Markdown: ``literal`` as code, :math:`x` as inline
    maths (``$x$``) and a ``.. math::`` block as display maths (``$$ … $$``), a cross-reference as the name it points
    to (``~`` keeps the last part, as Sphinx shows it), ``::`` as ``:``."""
    if not text:
        return ""
    text = inspect.cleandoc(text)

    def role(m):
        target = m.group(1)
        shown = target.rsplit(".", 1)[-1] if m.group(0).split("`", 1)[1].startswith("~") else target
        return f"`{shown}`"

    text = _ROLE.sub(role, text)
    text = re.sub(r":math:`([^`]+)`", r"$\1$", text)
    text = re.sub(r"^( *)\.\. math:: *(.*)$((?:\n\1 {3,}\S.*)*)",
                  lambda m: f"{m.group(1)}$$\n" + " ".join([m.group(2).strip()] + [
                      x.strip() for x in m.group(3).splitlines() if x.strip()]).strip() + f"\n{m.group(1)}$$",
                  text, flags=re.M)
    text = re.sub(r"``([^`]+)``", r"`\1`", text)
    return text.replace("::\n", ":\n")


_ITEM = re.compile(r"^( *)([-*+]|\d+\.) \S")


def sane_lists(text: str) -> str:
    """Markdown written for GitHub's renderer, made to read the same in Python-Markdown (the site's): a blank line
    before a list that follows a paragraph line (Python-Markdown runs it into the paragraph otherwise), and a list
    nested by 2 or 3 spaces indented to 4 with its continuation lines (Python-Markdown flattens it otherwise).
    Code fences are left alone."""
    lines, out, fence, nested = text.split("\n"), [], False, False
    for i, line in enumerate(lines):
        if line.lstrip().startswith("```"):
            fence = not fence
        m = None if fence else _ITEM.match(line)
        if fence:
            pass
        elif m and not m.group(1):
            nested = False
            before = lines[i - 1] if i else ""
            if before.strip() and not _ITEM.match(before) and not before.startswith((" ", "|", "#", ">", "```")):
                out.append("")
        elif m and len(m.group(1)) in (2, 3):
            nested, line = True, " " * (4 - len(m.group(1))) + line
        elif nested and line.startswith("    "):
            line = "  " + line
        elif not line.startswith(" "):
            nested = False
        out.append(line)
    return "\n".join(out)


#: A citation of the design notes, in code or not, with the sections it names (``ALGORITHMS.md §5, §7``)
_NOTES = re.compile(r"`?ALGORITHMS\.md`?((?:,? ?§\d+)*)")


@functools.cache
def algorithm_sections() -> dict:
    """``{number: (title, anchor)}`` of the numbered sections of the site's algorithms page (the design notes'
    numbering), read once from the page beside the package; empty where it is not there (an installed package)."""
    from markdown.extensions.toc import slugify

    page = Path(__file__).resolve().parents[1] / "docs" / "explanation" / "algorithms.md"
    if not page.is_file():
        return {}
    heads = re.findall(r"^## ((\d+)\. (.+))$", page.read_text(encoding="utf-8"), re.M)
    return {n: (title, slugify(head, "-")) for head, n, title in heads}


def link_design_notes(text: str, to_site_root: str) -> str:
    """``text`` with its citations of the design notes (``ALGORITHMS.md §n``, in code or not) as links to the site's
    algorithms page by its title and the section's (``[Algorithms §5: Spectrum, …](…#5-spectrum-…)``),
    ``to_site_root`` the relative path from the page to the site's root (``"../"``)."""
    sections = algorithm_sections()
    page = f"{to_site_root}explanation/algorithms.md"

    def cite(m: re.Match) -> str:
        numbers = re.findall(r"§(\d+)", m.group(1))
        if not numbers:
            return f"[Algorithms]({page})"
        return ", ".join(f"[Algorithms §{n}: {sections[n][0]}]({page}#{sections[n][1]})" if n in sections
                         else f"[Algorithms §{n}]({page})" for n in numbers)

    return _NOTES.sub(cite, text)


def _cell(x) -> str:
    return str(x).replace("|", "\\|").replace("\n", " ")


def _table(header: tuple, rows) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return out


#: What the effects page says of an effect without starts of its own (:class:`torchtea.fitting.starts.Starts`).
DEFAULT_START = ("the defaults: 0 for a free parameter, 1 for a positive one, the middle of a bounded range; a mean "
                 "that no regression takes by nonlinear least squares from there.")


def effects_page() -> str:
    """Every registered effect: its kind, inputs, IEEE 952 term, parameters (kind, unit, bounds), physics (its
    docstring), for those ``check`` screens the screen's test, and how the fits start it."""
    from .checking.screens import candidates, screen_test
    from .fitting.starts import Starts, starts_of
    from .noise.components import COMPONENTS
    from .noise.navigation import nav_term_of

    screened = candidates()
    lines = ["# Effects", "",
             "Every physical effect torchtea knows, as its registry has it when these pages are built "
             "(`torchtea.noise.components.COMPONENTS`; a model is a spec of them joined by `+`, e.g. "
             "`fractional+white+random-walk`). *Kind*: a **state** or **filter** is a linear Gaussian state-space "
             "block, a **measurement** adds white noise, a **mean** is a deterministic function of time and the "
             "input channels, a **modifier** changes another component. Parameters are given in natural units; "
             "*unit* is the channel's unit (m/s² for an accelerometer, rad/s for a gyroscope) unless it says "
             "otherwise. Effects a user registers (`torchtea.effects.register`, [Your own effect]"
             "(../howto/own-effect.md)) join this list and `check`'s screens.", "",
             f"`check` screens {len(screened)} of them, in this order: " + ", ".join(f"`{n}`" for n in screened)
             + ".", ""]
    for name, comp in COMPONENTS.items():
        facts = [f"kind **{comp.kind}**"]
        if comp.inputs:
            facts.append("reads the input " + ", ".join(f"`{i}`" for i in comp.inputs))
        term = nav_term_of(comp).term
        if term:
            facts.append(f"IEEE 952 term **{term}**")
        if comp.order_param:
            facts.append(f"its `{comp.order_param}` is the fractional order KFo estimates")
        if not comp.stationary:
            facts.append("not stationary: fitted by the exact likelihood only")
        facts.append("screened by `check`" if name in screened else "not screened (add it with `--add` or a model)")
        physics = link_design_notes(rst_to_markdown(type(comp).__doc__), "../")
        lines += [f"## `{name}`", "", "; ".join(facts) + ".", "", physics, ""]
        if comp.params:
            rows = [(f"`{name}.{p.name}`", p.kind, p.unit,
                     "" if p.bounds == (float("-inf"), float("inf")) else f"({p.bounds[0]:g}, {p.bounds[1]:g})")
                    for p in comp.params]
            lines += _table(("parameter", "transform", "unit", "bounds"), rows) + [""]
        test = screen_test(comp)
        if name in screened and test:
            lines += [f"**Screen**: {test}.", ""]
        own = type(starts_of(comp))
        doc = own.__doc__ or f"its own ({own.__name__})."
        words = DEFAULT_START if own is Starts else rst_to_markdown(doc.strip())
        lines += ["**Start**: " + words, ""]
    return "\n".join(lines) + "\n"


def diagnostics_page() -> str:
    """Every diagnostic ``check`` runs, in its order, from the functions that make them."""
    from .checking import diagnostics as dg

    lines = ["# Diagnostics", "", rst_to_markdown(dg.__doc__).split("\n\n")[0], "",
             f"Each is a test at level {dg.LEVEL:g} (`--level`) of \"the data came from the fitted model\", with the "
             "multiple comparisons inside it Bonferroni-corrected, so its p-value is the whole diagnostic's. They read "
             "the standardised innovations z of the exact Kalman filter at the fitted values — independent N(0, 1) "
             "when the model is right. Their false-alarm rates on data drawn from fitted models are measured in "
             "`experiments/check/` ([Studies](../studies/index.md)).", ""]
    for name, fn in dg.FUNCTIONS.items():
        lines += [f"## `{name}`", "", f"`torchtea.checking.diagnostics.{fn.__name__}`", "",
                  rst_to_markdown(fn.__doc__), ""]
    lines += ["## Metrics", "",
              "Descriptive, not tests: `nll_per_sample` (−ℓ/N of the exact filter, nats), `psd_misfit` (the "
              "spectrum diagnostic's mean |log₁₀| band ratio: 0 when the model's spectrum has the data's shape and "
              "level), `adev_misfit` (the Allan diagnostic's mean |log₁₀(ADEV data / ADEV model)|).", ""]
    return "\n".join(lines) + "\n"


def _subcommands(parser: argparse.ArgumentParser) -> dict:
    for action in parser._actions:  # argparse keeps its subcommands in its one sub-parsers action
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            return {name: (p, helps.get(name, "")) for name, p in action.choices.items()}
    return {}


def cli_page() -> str:
    """``torchtea``'s commands, each with its ``--help`` as the parser prints it."""
    from .cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "80"
    try:
        parser = build_parser()
        lines = ["# Command line", "",
                 "Every command of `torchtea` with its `--help`, printed by the parser itself when these pages were "
                 "built. The [guide](../guide/commands.md) shows them at work.", "",
                 "```text", parser.format_help().rstrip(), "```", ""]
        for name, (sub, text) in _subcommands(parser).items():
            lines += [f"## `torchtea {name}`", "", (text or "").replace("%%", "%"), "",
                      "```text", sub.format_help().rstrip(), "```", ""]
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(lines) + "\n"


def _meaning_table(meaning: dict) -> list[str]:
    return _table(("entry", "what it means"), ((f"`{k}`", v) for k, v in sorted(meaning.items()))) + [""]


def json_page() -> str:
    """The fields of the JSON files the commands write, from the ``meaning`` table each file carries."""
    from .checking.report import MEANING as CHECK_MEANING
    from .engines.presets import get_preset
    from .export.run import EXPORT_MEANING
    from .fitting.datasheet import VERDICT_MEANING
    from .fitting.recording import FIT_MEANING
    from .reports.identify import estimate_meaning
    from .reports.report import SUMMARY_MEANING
    from .sensors.measurements import RECORDING_MEANING

    n, k0 = 44_900, 29_934
    lines = ["# JSON outputs", "",
             "Every JSON file torchtea writes is strict (RFC 8259: `null` where there is no number). Those of "
             "`check`, `fit`, `export` and `identify` carry a `meaning` entry: what each of their entries means. "
             "The tables below are those entries, taken from the code when these pages were built (tests hold "
             "`check.json` and `fit --json` to them: every entry the files write is described). Numbers are in SI "
             "units of the channel (`unit`) unless the entry says otherwise. The others are described where they "
             "are made: the recorder's `REC.json` in the [recording format](../recording.md), a Monte Carlo "
             "study's `summary.json` and `sweep.json` in [its how-to](../howto/montecarlo.md); `plan --json` "
             "carries its own one-line `meaning`.", "",
             "## `check.json` (`torchtea check`)", "",
             "Per channel under `axes` (a single channel's entries also at the top level), with the recording's "
             "part below.", ""]
    lines += _meaning_table(dict(RECORDING_MEANING, **CHECK_MEANING))
    lines += ["## `fit --json` (`torchtea fit`)", ""] + _meaning_table(FIT_MEANING)
    lines += ["## `export.json` (`torchtea export`, `--export` of `fit` and `check`)", ""]
    lines += _meaning_table(EXPORT_MEANING)
    lines += ["### A datasheet verdict (`--datasheet`: `datasheet` of an axis)", "",
              f"Its `rows`, one per term (N, B, K): {VERDICT_MEANING}.", ""]
    lines += ["## `summary.json` (`torchtea identify`)", "",
              "Per axis under `axes`, the TEA's estimates; the spans below are those of a run of "
              f"{n} samples at 100 Hz with the paper's MEMS settings (a file names its own).", ""]
    lines += _meaning_table(dict(SUMMARY_MEANING, **estimate_meaning(k0, n, 0.01, get_preset("paper-mems-x"))))
    return "\n".join(lines) + "\n"


#: Each generated page: its path under ``docs/`` and the function that writes it.
PAGES = {"reference/effects.md": effects_page, "reference/diagnostics.md": diagnostics_page,
         "reference/cli.md": cli_page, "reference/json.md": json_page}
