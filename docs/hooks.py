"""MkDocs hooks of this site (mkdocs.yml ``hooks``): the package's docstrings cross-reference in reStructuredText
(:func:`~torchtea.noise.simulate_model`), which mkdocstrings renders as the role's name before a code span; show the
name alone, as Sphinx would (``~`` keeps its last part)."""
import re

_ROLE = re.compile(r":(?:func|class|meth|attr|data|mod|obj|exc|math):<code>(~?)([^<]+)</code>")


def _name(m: re.Match) -> str:
    target = m.group(2)
    return f"<code>{target.rsplit('.', 1)[-1] if m.group(1) else target}</code>"


def on_page_content(html: str, **kwargs) -> str:
    return _ROLE.sub(_name, html)
