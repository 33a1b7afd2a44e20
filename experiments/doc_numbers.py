"""Find measured numbers typed by hand into README and docs: a measurement (an error, a time, a ratio, a force read)
lives in a results file and reaches a document only through a generated block (experiments.doc_tables), so a
re-run updates the docs by regenerating them, never by rewriting prose.

What counts as a measured number: a digit followed by a unit a measurement is quoted in (%, N, mN, ms, s, min, h,
x, fps, um), or any number beside a ± sign. What does not: text inside a generated block, inside fenced or inline
code (commands, config keys), in an HTML comment or a link target, and the short allow-list below of physical
constants, sensor specifications and config defaults, each with the reason it is not a measurement.
"""

from __future__ import annotations

import re

# Phrases that carry a unit but are not measurements. Keep it short: a measurement that lands here silently
# escapes every regeneration. Each entry: the exact phrase (case-sensitive) -> why it is not measured.
ALLOWED = {
    "0.5-15 N": "the training presses' Fz range (config data.fz_min / fz_max)",
    "15 N": "the top of the training Fz range (config data.fz_max)",
    "25 fps": "the GelSight Mini's frame rate (sensor specification)",
    "40 ms": "the GelSight Mini's frame period at 25 fps (sensor specification)",
    "60 fps": "the DIGIT's frame rate at QVGA, the benchmark's DIGIT_FPS (sensor specification)",
    "100%": "a whole, not a measurement (e.g. 100% of a dataset)",
    "50%": "a share set by a config (a split, a probability), not a measurement",
}

_UNIT = r"(?:%|N|mN|ms|s|min|h|x|×|fps|um|µm)"
_NUM = r"\d[\d,]*(?:\.\d+)?(?:e-?\d+)?"
# "12.3%", "4.2-5.1 N", "0.3 to 0.5 s", "3.7x", "2,474 s"; not "Python 3.11", "Table II", "vit-xs", "10x10"
_MEASURED = re.compile(rf"(?<![\w.\-/#])[~≈<>]?{_NUM}(?:\s?(?:-|–|to)\s?{_NUM})?\s?{_UNIT}(?![\w/])")
_PLUS_MINUS = re.compile(rf"{_NUM}\s?±\s?{_NUM}|±\s?{_NUM}")

_GENERATED = re.compile(r"<!-- (?P<tag>result[\w-]*): [^>]*?-->.*?<!-- /(?P=tag) -->", re.S)
_FENCE = re.compile(r"^```.*?^```[^\n]*$", re.S | re.M)
_COMMENT = re.compile(r"<!--.*?-->", re.S)
_INLINE = re.compile(r"`[^`\n]*`")
_LINK_TARGET = re.compile(r"\]\([^)]*\)")


def _blank(match: re.Match) -> str:
    """The match replaced by spaces, its newlines kept: line numbers of what follows stay right."""
    return re.sub(r"[^\n]", " ", match.group(0))


def visible_prose(text: str) -> str:
    """The text with every part that may carry numbers blanked out (generated blocks, code, comments, links)."""
    # code first: a marker quoted in inline code (`<!-- result-include: FILE -->`) opens no block
    for pattern in (_FENCE, _INLINE, _GENERATED, _COMMENT, _LINK_TARGET):
        text = pattern.sub(_blank, text)
    for phrase in sorted(ALLOWED, key=len, reverse=True):
        text = re.sub(rf"(?<![\w.\-]){re.escape(phrase)}(?![\w])", lambda m: " " * len(m.group(0)), text)
    return text


def hand_typed(text: str) -> list[tuple[int, str]]:
    """(line number, the number as typed) for every measured number outside a generated block."""
    hits = []
    for lineno, line in enumerate(visible_prose(text).splitlines(), 1):
        for pattern in (_PLUS_MINUS, _MEASURED):
            for m in pattern.finditer(line):
                hits.append((lineno, m.group(0).strip()))
                line = line[:m.start()] + " " * (m.end() - m.start()) + line[m.end():]
    return sorted(hits)
