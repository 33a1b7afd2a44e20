"""No measured time in the code's own words (issue 62): a docstring, a comment or a --help text (help=, the
experiments' `costs`) of ffjax/, configs/ or experiments/ never types how long something took or how much faster
it ran. Such numbers go stale with the next run; they live in the results files and docs (docs/benchmarks.md,
docs/results/<preset>/reproduce.json), and a command that announces a duration reads it from there
(experiments.common.measured_cost). What stays: a parameter's value and unit, a default, a physical fact of the
world (a real recording's length), each named in ALLOWED with why."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("ffjax", "configs", "experiments")

_NUM = r"\d{1,3}(?:,\d{3})+(?:\.\d+)?|\d+(?:\.\d+)?"
TIME = re.compile(
    rf"(?<![\w.])[~<>]?\s?(?:{_NUM})(?:\s?(?:-|–|to)\s?(?:{_NUM}))?\s?"
    r"(?:ms|µs|us|s|secs?|seconds?|min|mins|minutes?|h|hrs?|hours?)\b"
    rf"|(?<![\w.])(?:{_NUM})\s?x (?:faster|slower|sooner)\b")

# (file, the text matched, whitespace collapsed): why it is no measurement of this code
ALLOWED = {
    ("ffjax/compile_cache.py", "1 s"): "jax's own threshold for caching a compiled program (a default of jax)",
    ("ffjax/live/tool.py", "0.5 s"): "--reconnect-wait's default",
    ("ffjax/live/tool.py", "8 s"): "the cap of --reconnect-wait's doubling (a parameter)",
    ("ffjax/live/tool.py", "3 minutes"): "the length of the real rest recording the LED drift was read from",
    ("ffjax/live/background.py", "3 minutes"): "the length of the real rest recording the LED drift was read from",
    ("ffjax/sim/sensors.py", "180 s"): "the length of the release's real rest recording (data, not a timing)",
    ("ffjax/sim/sensors.py", "3 minutes"): "the same recording's length",
    ("ffjax/tasks/pushing.py", "~1.5 s"): "the window of the push's pose corrections (a parameter)",
}
# quoting examples of what a number in the docs looks like is that module's job (the docs' own number check)
WHOLE_FILES = {"experiments/doc_numbers.py"}


def texts(path: Path):
    """(line, kind, text) for every docstring, comment and help-like string (help=, description=, epilog=,
    costs=) of a Python file."""
    src = path.read_text()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield node.body[0].lineno, "docstring", doc
        if isinstance(node, ast.Call):
            for kw in node.keywords:
                if kw.arg in ("help", "description", "epilog", "costs"):
                    parts = [n.value for n in ast.walk(kw.value)
                             if isinstance(n, ast.Constant) and isinstance(n.value, str)]
                    yield kw.value.lineno, kw.arg, " ".join(parts)
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], "comment", tok.string


def measured_times() -> list[str]:
    found = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel in WHOLE_FILES:
                continue
            for line, kind, text in texts(path):
                for m in TIME.finditer(text):
                    said = " ".join(m.group(0).split())
                    if (rel, said) not in ALLOWED:
                        context = " ".join(text[max(0, m.start() - 50):m.end() + 20].split())
                        found.append(f"{rel}:{line} ({kind}) {said!r}: ...{context}...")
    return found


def test_the_pattern_finds_times_and_ratios_not_sizes():
    hits = lambda s: [" ".join(m.group(0).split()) for m in TIME.finditer(s)]  # noqa: E731
    assert hits("took 11 min on 2 cores, 36 s on a GPU; 1-5 min; 750 ms; 2,474 s; 3.5x faster") == \
        ["11 min", "36 s", "1-5 min", "750 ms", "2,474 s", "3.5x faster"]
    assert hits("(B, 3, h, w) at 240x320, 15 N, 4.5 mm, Python 3.11, 2 seeds, 10 steps") == []


def test_no_docstring_comment_or_help_types_a_measured_time():
    found = measured_times()
    assert not found, ("measured times typed into the code (move them to the results or docs and point there, "
                       "or add a parameter to ALLOWED with why):\n" + "\n".join(found))
