"""README's results table, generated from the published results it cites, so the two cannot disagree.

    python -m experiments.readme_table            # rewrite README's table from the folders its marker names
    python -m experiments.readme_table --check    # exit 1 when README's table differs from its results

README holds the table between `<!-- results-table: FOLDER [SEEDS_FOLDER] -->` and `<!-- /results-table -->`:
FOLDER is an ablation results folder (every method), SEEDS_FOLDER optionally one with more seeds for some
methods, shown beside the first as "(3 seeds: mean ± std)". The test suite runs the check.
"""

from __future__ import annotations

import argparse
import re
import sys

from experiments import common, style
from experiments import paper_numbers as P

README = common.ROOT / "README.md"
_BLOCK = re.compile(r"(<!-- results-table: (?P<args>[^>]*?) -->\n)(?P<body>.*?)(<!-- /results-table -->)", re.S)
_CALIB = ("mini-2/gel-1", "mini-3/gel-2")


def _f(x: float) -> str:
    return f"{x:.1f}"


def table(main: dict, more_seeds: dict | None = None) -> str:
    """The markdown table: validation, Tables I-III of `main` with the paper's row under each; a method that
    `more_seeds` also holds gets its mean ± std over those seeds beside Tables I and II."""
    methods = list(main["table1"])
    extra = more_seeds or {}

    def with_seeds(key: str, m: str) -> str:
        cell = _f(main[key][m]["mean"]["mean"])
        if m in extra.get(key, {}) and len(extra.get("seeds", [])) >= 2:
            cell += f" ({len(extra['seeds'])} seeds: {common.fmt(extra[key][m]['mean'])})"
        return cell

    def paper(numbers: dict, pick) -> list:
        return [pick(numbers[m]) if m in numbers else "–" for m in methods]

    val = main["training"]["methods"]
    rows = [
        ["validation, training sensor", *(_f(val[m]["val_nl1"]["mean"]) for m in methods)],
        ["Table I, 10 unseen objects", *(with_seeds("table1", m) for m in methods)],
        ["paper", *paper(P.TABLE1, lambda v: _f(v[-1]))],
        ["Table II, 9 GelSight units × gels", *(with_seeds("table2", m) for m in methods)],
        ["paper", *paper(P.TABLE2, lambda v: _f(v[-1]))],
        ["Table III, after calibration (mini-2 gel 1 / mini-3 gel 2)",
         *(" / ".join(_f(main["table3"][m][t]["after"]["mean"]) for t in _CALIB) for m in methods)],
        ["paper", *paper(P.TABLE3, lambda v: f"{_f(v[0])} / {_f(v[1])}")],
    ]
    return common.md_table(["", *(style.name(m) for m in methods)], rows)


def _render(match: re.Match) -> str:
    folders = match.group("args").split()
    loaded = []
    for f in folders:
        results = common.read_json(common.ROOT / f / "results.json")
        if results is None:
            raise FileNotFoundError(f"README.md's results-table names {f}, which holds no results.json")
        loaded.append(results)
    return match.group(1) + table(*loaded).rstrip("\n") + "\n" + match.group(4)


def regenerate(text: str) -> str:
    """README text with every results-table block rewritten from its folders."""
    if not _BLOCK.search(text):
        raise ValueError("README.md has no <!-- results-table: FOLDER --> ... <!-- /results-table --> block")
    return _BLOCK.sub(_render, text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=common.prog(), description=__doc__.strip().splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 when README differs")
    args = ap.parse_args(argv)
    text = README.read_text()
    new = regenerate(text)
    if args.check:
        if new != text:
            print("README.md's results table differs from its results: python -m experiments.readme_table",
                  file=sys.stderr)
            return 1
        print("README.md's results table matches its results")
        return 0
    if new != text:
        common.write_text(README, new)
    print(f"{'rewrote' if new != text else 'unchanged:'} {README.name}'s results table")
    return 0


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
