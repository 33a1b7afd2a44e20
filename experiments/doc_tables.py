"""The result tables in README and docs/*.md, generated from the published results they cite, so the text and
the results cannot disagree.

    python -m experiments.doc_tables            # rewrite every generated table from the results it names
    python -m experiments.doc_tables --check    # exit 1 when a document's table differs from its results

Two kinds of block, each between an opening marker and its closing one:
- `<!-- results-table: FOLDER [SEEDS_FOLDER] -->` ... `<!-- /results-table -->` (README): validation and
  Tables I-III of an ablation results folder, the paper's row under each, mean ± std where it has 2+ seeds;
  SEEDS_FOLDER optionally one with more seeds for some methods, shown beside the first.
- `<!-- result-include: FILE.md[#TEXT] -->` ... `<!-- /result-include -->` (any document): the first Markdown
  table of a result's FILE.md (a path from the repository root; after the first line holding TEXT), as it is.
- `<!-- result-text: FILE.json KEY.PATH [TEMPLATE] -->` ... `<!-- /result-text -->` (any document, inline or on
  its own lines): one value of a results file: a sentence as written there (a finding), a number through TEMPLATE
  (a str.format template such as `{:.1f}%`; without one, as JSON writes it); a value of several lines (a list)
  starts on the line after the marker. KEY.PATH walks dicts by key and lists
  by index (a key that itself holds dots, such as a share "0.5", is found too); KEY.PATH/N divides a number by N
  (`wall_s/60`: minutes).
Outside generated blocks a measured number may not be typed (experiments.doc_numbers): `--check` fails on one.
The test suite runs the check.
"""

from __future__ import annotations

import argparse
import json
import re
import sys

from experiments import common, doc_numbers, style
from experiments import paper_numbers as P

README = common.ROOT / "README.md"
DOCUMENTS = (README, *sorted((common.ROOT / "docs").glob("*.md")))


def _block(tag: str) -> re.Pattern:
    """`<!-- TAG: ARGS -->` ... `<!-- /TAG -->`: groups 1 (the opening line), args, body and 4 (the closing)."""
    return re.compile(rf"(<!-- {tag}: (?P<args>[^>]*?) -->\n)(?P<body>.*?)(<!-- /{tag} -->)", re.S)


_BLOCK, _INCLUDE = _block("results-table"), _block("result-include")
# inline: the opening marker, the value and the closing marker may share a line
_TEXT = re.compile(r"(<!-- result-text: (?P<args>[^>]*?) -->)(?P<body>.*?)(<!-- /result-text -->)", re.S)
_CALIB = ("mini-2/gel-1", "mini-3/gel-2")


def _f(x: float) -> str:
    return f"{x:.1f}"


def table(main: dict, more_seeds: dict | None = None) -> str:
    """The markdown table: validation, Tables I-III of `main` with the paper's row under each; a method that
    `more_seeds` also holds gets its mean ± std over those seeds beside Tables I and II."""
    methods = list(main["table1"])
    extra = more_seeds or {}

    n = len(main.get("seeds", []))

    def cell(ms: dict) -> str:  # mean ± std over the folder's seeds; the mean alone for one seed
        return common.fmt(ms) if n >= 2 else _f(ms["mean"])

    def with_seeds(key: str, m: str) -> str:
        text = cell(main[key][m]["mean"])
        if m in extra.get(key, {}) and len(extra.get("seeds", [])) >= 2:
            text += f" ({len(extra['seeds'])} seeds: {common.fmt(extra[key][m]['mean'])})"
        return text

    def paper(numbers: dict, pick) -> list:
        return [pick(numbers[m]) if m in numbers else "–" for m in methods]

    val = main["training"]["methods"]
    rows = [
        ["validation, training sensor", *(cell(val[m]["val_nl1"]) for m in methods)],
        ["Table I, 10 unseen objects", *(with_seeds("table1", m) for m in methods)],
        ["paper", *paper(P.TABLE1, lambda v: _f(v[-1]))],
        ["Table II, 9 GelSight units × gels", *(with_seeds("table2", m) for m in methods)],
        ["paper", *paper(P.TABLE2, lambda v: _f(v[-1]))],
        ["Table III, after calibration (mini-2 gel 1 / mini-3 gel 2)",
         *(" / ".join(cell(main["table3"][m][t]["after"]) for t in _CALIB) for m in methods)],
        ["paper", *paper(P.TABLE3, lambda v: f"{_f(v[0])} / {_f(v[1])}")],
    ]
    return common.md_table(["", *(style.name(m) for m in methods)], rows)


def _render(match: re.Match) -> str:
    folders = match.group("args").split()
    loaded = []
    for f in folders:
        results = common.read_json(common.ROOT / f / "results.json")
        if results is None:
            raise FileNotFoundError(f"a results-table block names {f}, which holds no results.json")
        loaded.append(results)
    return match.group(1) + table(*loaded).rstrip("\n") + "\n" + match.group(4)


def first_table(text: str) -> str:
    """The first Markdown table of a text: its consecutive lines that start with '|'."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith("|")), None)
    if start is None:
        return ""
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    return "\n".join(lines[start:end])


def _include(match: re.Match) -> str:
    """FILE.md: its first table; FILE.md#TEXT: its first table after the first line holding TEXT."""
    name, _, after = match.group("args").strip().partition("#")
    path = common.ROOT / name
    if not path.is_file():
        raise FileNotFoundError(f"a result-include block names {path.relative_to(common.ROOT)}, which does not exist")
    text = path.read_text()
    if after and after not in text:
        raise ValueError(f"{path.relative_to(common.ROOT)} holds no {after!r} to include a table after")
    body = first_table(text[text.index(after):] if after else text)
    if not body:
        raise ValueError(f"{path.relative_to(common.ROOT)} holds no Markdown table to include"
                         + (f" after {after!r}" if after else ""))
    return match.group(1) + body + "\n" + match.group(4)


def lookup(tree, path: str):
    """The value at a dotted KEY.PATH of a JSON tree (list items by index); a key holding dots is found whole."""
    parts, node = path.split("."), tree
    while parts:
        for n in range(len(parts), 0, -1):  # the longest key first: "per_share.0.5.mean" finds "0.5"
            key = ".".join(parts[:n])
            if isinstance(node, dict) and key in node:
                node, parts = node[key], parts[n:]
                break
            if isinstance(node, list) and n == 1 and key.lstrip("-").isdigit() and -len(node) <= int(key) < len(node):
                node, parts = node[int(key)], parts[1:]
                break
        else:
            raise KeyError(path)
    return node


def _text(match: re.Match) -> str:
    name, path, *template = match.group("args").split(maxsplit=2)
    file = common.ROOT / name
    results = common.read_json(file)
    if results is None:
        raise FileNotFoundError(f"a result-text block names {name}, which does not exist or is not JSON")
    path, _, divisor = path.partition("/")
    try:
        value = lookup(results, path)
        if divisor:
            value = value / float(divisor)
    except KeyError:
        raise KeyError(f"{name} holds no {path!r} (a result-text block names it)") from None
    if template:
        body = template[0].format(value)
    elif isinstance(value, str):
        body = value
    else:
        body = json.dumps(value)
    if "\n" in body:  # a list or paragraphs: on lines of their own, so Markdown renders them (not the marker's line)
        body = "\n" + body.strip("\n") + "\n"
    return match.group(1) + body + match.group(4)


def regenerate(text: str) -> str:
    """A document's text with every generated block rewritten from the results it names."""
    return _TEXT.sub(_text, _INCLUDE.sub(_include, _BLOCK.sub(_render, text)))


def hand_typed_numbers(documents=None) -> list[tuple[str, int, str]]:
    """(document, line, number) for every measured number typed by hand in README and docs/*.md."""
    return [(str(doc.relative_to(common.ROOT) if doc.is_relative_to(common.ROOT) else doc), lineno, number)
            for doc in (documents or DOCUMENTS) for lineno, number in doc_numbers.hand_typed(doc.read_text())]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 when a document differs")
    args = ap.parse_args(argv)
    if not _BLOCK.search(README.read_text()):
        raise ValueError("README.md has no <!-- results-table: FOLDER --> ... <!-- /results-table --> block")
    differ = []
    for doc in DOCUMENTS:
        text = doc.read_text()
        new = regenerate(text)
        if new != text:
            differ.append(doc.relative_to(common.ROOT) if doc.is_relative_to(common.ROOT) else doc)
            if not args.check:
                common.write_text(doc, new)
    typed = hand_typed_numbers()
    for doc, lineno, number in typed:
        print(f"{doc}:{lineno}: {number!r} is a measured number typed by hand: quote it from its results file "
              "through a generated block (see python -m experiments.doc_tables --help), or, if it is a constant "
              "or a config default, add it to experiments/doc_numbers.ALLOWED with why", file=sys.stderr)
    if args.check:
        if differ:
            print(f"tables differ from their results in {', '.join(map(str, differ))}: python -m "
                  "experiments.doc_tables", file=sys.stderr)
        if differ or typed:
            return 1
        print("every generated block matches its results and no measured number is typed by hand")
        return 0
    if typed:
        return 1
    print(f"rewrote {', '.join(map(str, differ))}" if differ else "every generated table was already current")
    return 0


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
