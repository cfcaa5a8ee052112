"""Escaping of untrusted text (fiducial and target ids, paths, units, frames) for every text
output: one function per output kind.

- :func:`terminal`: the terminal and the text report. Control characters (C0, DEL, C1: ANSI
  escape sequences, carriage returns, line breaks, bells) and the Unicode format characters that
  reorder or hide text (bidi overrides, zero-width characters) are shown as Python escapes
  (``\\x1b``, ``\\n``, ``\\u202e``), so a value is always one visible line.
- :func:`markdown`: Markdown text and table cells: :func:`terminal` first (no line breaks, so no
  new heading, list or table row), then HTML's ``& < >`` as entities (no tags, no autolinks) and
  a backslash before every character Markdown gives a meaning inline (``\\ ` * _ [ ] ( ) # | !
  ~ { } +``): no emphasis, link, image, heading or table cell comes out of a value.
- :func:`markdown_code`: a Markdown code span: :func:`terminal` first, then a backtick fence
  longer than any run of backticks in the value (CommonMark, "code spans").
- :func:`xml_attribute`: an XML attribute value, quotes included (URDF, xacro): :func:`terminal`
  first (XML 1.0 allows no control characters), then ``& < > "`` as entities, so a value never
  ends the attribute or opens a tag.
- :func:`xml_comment`: text inside an XML comment: :func:`terminal` first, then a space after
  each ``-`` that a ``-`` follows, so no ``--`` (which XML forbids there) and no ``-->``.

JSON needs none of this (``json.dumps`` escapes every control character).
"""

from __future__ import annotations

import re
import unicodedata

#: Markdown characters escaped with a backslash (CommonMark allows it before any ASCII
#: punctuation); ``& < >`` become HTML entities instead.
MARKDOWN_SPECIAL = "\\`*_[]()#|!~{}+"
_HTML = {"&": "&amp;", "<": "&lt;", ">": "&gt;"}
_MD_TABLE = str.maketrans({**{c: "\\" + c for c in MARKDOWN_SPECIAL}, **_HTML})


def _hidden(ch: str) -> bool:
    # Cc: C0, DEL and C1 controls; Cf: bidi overrides/isolates, zero-width characters, BOM;
    # Zl/Zp: the Unicode line and paragraph separators.
    return unicodedata.category(ch) in ("Cc", "Cf", "Zl", "Zp")


def _escape_char(ch: str) -> str:
    if ch in _NAMED:
        return _NAMED[ch]
    code = ord(ch)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def terminal(value: object) -> str:
    """``value`` as text safe to print: control and invisible format characters escaped."""
    text = str(value)
    if text.isprintable():      # the common case; isprintable() is False for every hidden one
        return text
    return "".join(_escape_char(ch) if _hidden(ch) else ch for ch in text)


def markdown(value: object) -> str:
    """``value`` as literal Markdown text (paragraphs, headings and table cells)."""
    return terminal(value).translate(_MD_TABLE)


def markdown_code(value: object) -> str:
    """``value`` as a Markdown code span, fence included (shown literally, in monospace)."""
    text = terminal(value)
    longest = max((len(run) for run in re.findall("`+", text)), default=0)
    fence = "`" * (longest + 1)
    pad = " " if text.startswith("`") or text.endswith("`") or not text.strip(" ") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


_XML_ATTRIBUTE = {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}


def xml_attribute(value: object) -> str:
    """``value`` as a double-quoted XML attribute value (``"..."``, quotes included)."""
    return '"' + "".join(_XML_ATTRIBUTE.get(ch, ch) for ch in terminal(value)) + '"'


def xml_comment(value: object) -> str:
    """``value`` as text for an XML comment, one line without ``--``; close the comment with
    ``" -->"`` (a space first, so a last ``-`` does not touch it)."""
    return re.sub("-(?=-)", "- ", terminal(value))
