"""MkDocs hook: every formula of the site is rendered to MathML while the site builds.

``pymdownx.arithmatex`` (``generic: true``) leaves each formula as TeX in
``<span class="arithmatex">\\(...\\)</span>`` (inline) or ``<div class="arithmatex">\\[...\\]</div>``
(display). :func:`on_page_content` replaces the TeX with MathML made by the pure-Python
``latex2mathml``; Chromium, Firefox and Safari draw MathML Core themselves, so the formulas show
with no script and no network: from ``file://``, offline, in the browser tests. The wrapper stays
(Material styles ``div.arithmatex``: centred, scrolling sideways on a narrow screen).

Strict, like the rest of the build: a formula that cannot be rendered stops it with one line
naming the page and the formula. ``latex2mathml`` raises on some mistakes (``x^``, an unclosed
``\\left``) but passes others through silently, so its output is checked too: an unknown command
comes out as ``<mi>\\foo</mi>``, an unknown environment is dropped (``aligned`` leaves its ``&``
raw), ``\\frac{a}`` makes an ``<mfrac>`` of one child, a ``<`` inside ``\\text`` is not escaped.

Spellings ``latex2mathml`` needs: ``\\thicksim`` for the relation ``\\sim`` (it turns ``\\sim``
into a tilde); ``cases``, ``array``, ``matrix``, ``align``/``align*`` and ``split`` but no
``aligned`` or ``gathered``.

Browsers' MathML Core ignores ``mathvariant`` except ``normal``, so a ``\\mathbb{1}`` would show as a
plain 1 in Chromium: such letters and digits are replaced by the Unicode mathematical
alphanumeric characters (``\\mathbb{1}`` -> U+1D7D9), as ``latex2mathml`` already does for most.
A slash gets TeX's spacing (none) rather than the MathML operator dictionary's.
"""

from __future__ import annotations

import html
import logging
import re
import unicodedata
import xml.etree.ElementTree as ET
from typing import Any

FORMULA = re.compile(r'<(?P<tag>span|div) class="arithmatex">(?P<tex>.*?)</(?P=tag)>', re.DOTALL)
NS = "{http://www.w3.org/1998/Math/MathML}"
ARITY = {"mfrac": 2, "msub": 2, "msup": 2, "mroot": 2, "munder": 2, "mover": 2, "msubsup": 3, "munderover": 3}
#: mathvariant -> the words of its characters' Unicode names (then the Letterlike Symbols' spelling).
VARIANTS = {
    "bold": ("MATHEMATICAL BOLD",), "italic": ("MATHEMATICAL ITALIC",),
    "bold-italic": ("MATHEMATICAL BOLD ITALIC",),
    "double-struck": ("MATHEMATICAL DOUBLE-STRUCK", "DOUBLE-STRUCK"),
    "script": ("MATHEMATICAL SCRIPT", "SCRIPT"), "bold-script": ("MATHEMATICAL BOLD SCRIPT",),
    "fraktur": ("MATHEMATICAL FRAKTUR", "BLACK-LETTER"), "bold-fraktur": ("MATHEMATICAL BOLD FRAKTUR",),
    "sans-serif": ("MATHEMATICAL SANS-SERIF",), "bold-sans-serif": ("MATHEMATICAL SANS-SERIF BOLD",),
    "sans-serif-italic": ("MATHEMATICAL SANS-SERIF ITALIC",),
    "sans-serif-bold-italic": ("MATHEMATICAL SANS-SERIF BOLD ITALIC",),
    "monospace": ("MATHEMATICAL MONOSPACE",),
}
VARIANT_TOKEN = re.compile(r'<(?P<tag>mi|mn|mo|mtext) mathvariant="(?P<variant>[a-z-]+)">(?P<text>[^<]*)</(?P=tag)>')

STATS = {"pages": 0, "formulas": 0}


class FormulaError(ValueError):
    """A formula ``latex2mathml`` cannot render; the message says why."""


def _environments() -> set[str]:
    from latex2mathml import commands

    return {name.lstrip("\\") for name in commands.MATRICES}


def _styled(char: str, variant: str) -> str | None:
    """``char`` in ``variant`` as one Unicode character (``1``, double-struck -> U+1D7D9), or None."""
    try:
        name = unicodedata.name(char)
    except ValueError:
        return None
    base = name.replace("LATIN ", "").replace("GREEK ", "").replace("LETTER ", "")
    for prefix in VARIANTS.get(variant, ()):
        try:
            return unicodedata.lookup(f"{prefix} {base}")
        except KeyError:
            continue
    return None


def _unicode_variants(mathml: str) -> str:
    """Tokens styled by ``mathvariant`` (which MathML Core ignores) spelled in styled characters."""

    def replace(match: re.Match[str]) -> str:
        text = html.unescape(match["text"])
        styled = [_styled(c, match["variant"]) for c in text]
        if not text or None in styled:
            return match.group(0)  # no such character: Firefox and Safari still honour the attribute
        return f"<{match['tag']}>{html.escape(''.join(styled), quote=False)}</{match['tag']}>"  # type: ignore[arg-type]

    return VARIANT_TOKEN.sub(replace, mathml)


def _check(tex: str, mathml: str) -> None:
    """Raise FormulaError where ``latex2mathml`` passed a mistake through silently."""
    unknown = re.search(r"\\[A-Za-z]+|\\.", mathml)  # its own output spells every symbol as an entity
    if unknown:
        raise FormulaError(f"unknown command {unknown.group(0)}")
    for env in re.findall(r"\\begin\{([^}]*)\}", tex):
        if env not in _environments():
            raise FormulaError(f"environment {{{env}}} is not supported by latex2mathml")
    try:
        root = ET.fromstring(mathml)
    except ET.ParseError as exc:
        raise FormulaError(f"latex2mathml made malformed MathML ({exc}): a stray & or < ?") from exc
    for element in root.iter():
        tag = element.tag.removeprefix(NS)
        if tag in ARITY and len(element) != ARITY[tag]:
            raise FormulaError(f"<{tag}> with {len(element)} arguments instead of {ARITY[tag]}")


def _tex_spacing(mathml: str) -> str:
    """TeX spacing where the MathML operator dictionary differs: a slash is an ordinary symbol in TeX
    (``(r/300 - 50c)/51``), a spaced operator in MathML."""
    return mathml.replace("<mo>&#x0002F;</mo>", '<mo lspace="0" rspace="0">&#x0002F;</mo>')


def to_mathml(tex: str, display: bool = False) -> str:
    """The MathML of one formula (TeX without its delimiters); FormulaError if it has a mistake."""
    from latex2mathml.converter import convert

    if not tex.strip():
        raise FormulaError("empty formula")
    try:
        mathml = convert(tex, display="block" if display else "inline")
    except Exception as exc:  # latex2mathml's exceptions share no base class beyond Exception
        raise FormulaError(f"{type(exc).__name__} {exc}".strip()) from exc
    _check(tex, mathml)
    return _tex_spacing(_unicode_variants(mathml))


def _strip_delimiters(tex: str) -> str:
    tex = tex.strip()
    for start, end in (("\\(", "\\)"), ("\\[", "\\]"), ("$$", "$$"), ("$", "$")):
        if tex.startswith(start) and tex.endswith(end) and len(tex) >= len(start) + len(end):
            return tex[len(start):len(tex) - len(end)]
    return tex  # \begin{env}...\end{env} blocks come without delimiters


def render_formulas(content: str, where: str) -> tuple[str, int]:
    """``content`` (a page's HTML) with every arithmatex formula as MathML, and how many there were.

    Raises ``mkdocs.exceptions.PluginError`` (which stops the build) naming ``where`` and the formula.
    """
    count = 0

    def replace(match: re.Match[str]) -> str:
        nonlocal count
        tex = _strip_delimiters(html.unescape(match["tex"]))
        try:
            mathml = to_mathml(tex, display=match["tag"] == "div")
        except FormulaError as exc:
            from mkdocs.exceptions import PluginError

            raise PluginError(f'{where}: cannot render the formula "{" ".join(tex.split())}" as MathML: {exc}') from None
        count += 1
        return f'<{match["tag"]} class="arithmatex">{mathml}</{match["tag"]}>'

    return FORMULA.sub(replace, content), count


def on_page_content(content: str, page: Any, config: Any, files: Any) -> str:
    content, count = render_formulas(content, page.file.src_uri)
    STATS["formulas"] += count
    STATS["pages"] += bool(count)
    return content


def on_pre_build(config: Any) -> None:
    STATS.update(pages=0, formulas=0)  # mkdocs serve rebuilds in the same process


def on_post_build(config: Any) -> None:
    logging.getLogger("mkdocs.hooks.mathml").info(
        f"formulas rendered to MathML: {STATS['formulas']} on {STATS['pages']} page(s)")
