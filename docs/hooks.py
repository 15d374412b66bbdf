"""MkDocs hooks of this site (mkdocs.yml ``hooks``).

- The package's docstrings cross-reference in reStructuredText (:func:`~torchtea.noise.simulate_model`), which
  mkdocstrings renders as the role's name before a code span: the name alone is shown, as Sphinx would (``~`` keeps
  its last part).
- Maths — ``$…$`` and ``$$…$$`` on the pages (pymdownx.arithmatex), ``:math:`…``` in the docstrings — is written
  out as MathML when the site is built (latex2mathml), which browsers render themselves: the pages need no script
  and no network to show it."""
import html
import re

from latex2mathml.converter import convert

_ROLE = re.compile(r":(?:func|class|meth|attr|data|mod|obj|exc):<code>(~?)([^<]+)</code>")
_MATH_ROLE = re.compile(r":math:<code>([^<]+)</code>")
_INLINE = re.compile(r'<span class="arithmatex">\\\((.*?)\\\)</span>', re.S)
_BLOCK = re.compile(r'<div class="arithmatex">\\\[(.*?)\\\]</div>', re.S)


def _name(m: re.Match) -> str:
    target = m.group(2)
    return f"<code>{target.rsplit('.', 1)[-1] if m.group(1) else target}</code>"


def mathml(latex: str, display: str = "inline") -> str:
    """The LaTeX ``latex`` (HTML-escaped as the page holds it) as MathML."""
    return convert(html.unescape(latex).strip(), display=display)


def on_page_content(page_html: str, **kwargs) -> str:
    page_html = _BLOCK.sub(lambda m: mathml(m.group(1), "block"), page_html)
    page_html = _INLINE.sub(lambda m: mathml(m.group(1)), page_html)
    page_html = _MATH_ROLE.sub(lambda m: mathml(m.group(1)), page_html)
    return _ROLE.sub(_name, page_html)
