"""Which published results are current: each results folder against the code at HEAD.

    python -m experiments.status [ROOT] [--stale] [--check] [--index]

A result records the commit it ran (results.json "commit"); its experiment (experiments.catalog) names the
sources its numbers and its figures come from. At HEAD a result is
- current: none of those sources changed since its commit (a change of docstrings, comments or layout is none,
  nor is a file moved elsewhere, nor a change of the simulator that `experiments.same_output` certified renders
  the same bytes, except for the benchmarks that time it), and its figures' sources not since it was last drawn;
- replot: only the sources of its tables' text and figures changed since it was drawn
  (`python -m experiments.replot FOLDER` redraws it and records the commit it drew with);
- stale: a source of its numbers changed (the files are listed), it ran on uncommitted code ("-dirty"), its
  commit is not in this history, or a result whose trained runs it reads is stale.
The notebooks (experiments.notebooks) are listed after them, current when their outputs were made from today's
cells, code and published results. --check exits 1 when any result or notebook is not current; --index writes
ROOT/README.md, the index of every result (what it answers, the command, commit, seeds, wall time, state). ROOT
defaults to docs/results (the notebooks show that tree: they are listed for it alone).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import subprocess
from pathlib import Path

from experiments import catalog, common


@dataclasses.dataclass
class Result:
    """One published result folder and its state at HEAD."""

    folder: Path
    experiment: catalog.Experiment | None
    results: dict
    state: str = "current"  # current | replot | stale
    why: list = dataclasses.field(default_factory=list)

    @property
    def commit(self) -> str:
        return str(self.results.get("commit", ""))


def _git(*args, root=None) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=root or common.ROOT, capture_output=True, text=True)


def _under(path: str, paths) -> bool:
    return any(path == p or path.startswith(p.rstrip("/") + "/") for p in paths)


def _code(text: str | None, path: str):
    """A Python file's code without its docstrings (ast.dump: comments and layout are gone already), or None
    for another file or one that does not parse: then only identical text counts as the same."""
    if text is None or not path.endswith(".py"):
        return None
    try:
        tree = ast.parse(text)
    except SyntaxError:
        return None
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree)


def _same_code(commit: str, old: str, new: str, root=None, head: str = "HEAD") -> bool:
    """Whether `old` at commit and `new` at `head` hold the same code (text, or a Python file's docstring-free
    syntax tree)."""
    a, b = (_git("show", f"{rev}:{p}", root=root) for rev, p in ((commit, old), (head, new)))
    if a.returncode or b.returncode:
        return False
    if a.stdout == b.stdout:
        return True
    before = _code(a.stdout, old)
    return before is not None and before == _code(b.stdout, new)


def certified(commit: str, root=None) -> set[str]:
    """The simulator's files whose change since `commit` certificates vouch for (`experiments.same_output`: the
    code of a certificate's base and of its head rendered the same bytes). They chain, in the order recorded: a
    certificate whose base holds the code the files hold by then (at `commit`, or at the head of the certificate
    before) moves them to its head's code; the files that end at the code HEAD holds are vouched for."""
    from experiments import same_output

    at: dict[str, str] = {}  # file -> the commit whose code it holds after the certificates so far
    for c in same_output.certificates(root):
        if all(_same_code(at.get(f, commit), f, f, root, head=c["base"]) for f in c["files"]):
            at.update(dict.fromkeys(c["files"], c["head"]))
    return {f for f, rev in at.items() if _same_code(rev, f, f, root)}


def changed_since(commit: str, paths, root=None, certificates: bool = False) -> list[str] | None:
    """Files under `paths` whose code differs between `commit` and HEAD (committed changes only), or None when
    the commit is not in this repository's history. A change of docstrings, comments or layout only is no change
    of numbers; a file moved out of `paths` (git's rename detection) is not one either: what used it changed
    too, and is named. certificates: nor is a change of the simulator certified to render the same bytes."""
    if _git("cat-file", "-e", f"{commit}^{{commit}}", root=root).returncode != 0:
        return None
    r = _git("diff", "--name-status", "-M", commit, "HEAD", root=root)
    out = []
    for line in r.stdout.splitlines():
        kind, *names = line.split("\t")
        old, new = names[0], names[-1]
        if kind[0] == "R" and not _under(new, paths):
            continue  # moved out: the new place is someone else's source
        if not (_under(new, paths) or _under(old, paths)):
            continue
        if kind[0] in "MR" and _same_code(commit, old, new, root):
            continue
        out.append(new)
    if out and certificates:
        vouched = certified(commit, root)
        out = [f for f in out if f not in vouched]
    return out


def find(root) -> list[Path]:
    """Every folder under root holding a results.json, sorted."""
    return sorted(p.parent for p in Path(root).rglob("results.json"))


def check(folder) -> Result:
    """The state of one result folder at HEAD (without what it reuses: see check_all)."""
    folder = Path(folder)
    results = common.read_json(folder / "results.json") or {}
    r = Result(folder, catalog.kind_of(results), results)
    commit = r.commit
    if r.experiment is None:
        r.state, r.why = "stale", ["no experiment in experiments.catalog writes results like these"]
        return r
    if not commit or commit == "unknown":
        r.state, r.why = "stale", ["no commit recorded"]
        return r
    if commit.endswith("-dirty"):
        r.state, r.why = "stale", [f"ran on uncommitted changes to {commit[:7]}"]
        return r
    numbers = changed_since(commit, r.experiment.number_sources, certificates=not r.experiment.speed)
    if numbers is None:
        r.state, r.why = "stale", [f"commit {commit[:7]} is not in this history"]
    elif numbers:
        r.state, r.why = "stale", numbers
    else:
        drawn = str(results.get("replotted", commit))  # experiments.replot records the commit it drew with
        drawn = commit if drawn.endswith("-dirty") else drawn
        figures = changed_since(drawn, r.experiment.figures) if r.experiment.figures else []
        if figures:
            r.state, r.why = "replot", figures
    return r


def check_all(root) -> list[Result]:
    """Every result under root; one that reads another experiment's runs (from the same folder tree) is stale
    when that one is."""
    rows = [check(f) for f in find(root)]
    by_name = {(r.folder.parent, r.experiment.name): r for r in rows if r.experiment}
    for r in rows:
        if r.experiment and r.experiment.reuses and r.state != "stale":
            source = by_name.get((r.folder.parent, r.experiment.reuses))
            if source is not None and source.state == "stale":
                r.state, r.why = "stale", [f"reads {source.folder.name}, which is stale"]
    return rows


def _why(r: Result, n: int = 4) -> str:
    """The reasons, changed files grouped by folder ("ffjax/sim (12 files)"), the folders with most first."""
    if not r.why or " " in r.why[0]:  # a sentence, not changed files
        return ", ".join(r.why)
    groups: dict = {}
    for f in r.why:
        groups.setdefault(str(Path(f).parent) if "/" in f else f, []).append(f)
    ranked = sorted(groups.items(), key=lambda kv: -len(kv[1]))
    text = [k if len(v) == 1 and k == v[0] else f"{k} ({len(v)} file{'s' * (len(v) > 1)})" for k, v in ranked[:n]]
    return ", ".join(text) + (f" (+{len(ranked) - n} folders)" if len(ranked) > n else "")


def table(rows, root) -> str:
    """Markdown: folder, experiment, preset, commit, state and why."""
    return common.md_table(
        ["result", "experiment", "preset", "commit", "state", "why"],
        [[str(r.folder.relative_to(root)), r.experiment.name if r.experiment else "?",
          r.results.get("preset", "-"), f"`{r.commit[:7]}`" if r.commit else "-", r.state, _why(r) or "-"]
         for r in rows])


def _seeds(results: dict, experiment=None) -> str:
    """Seeds per cell: '3', or '1-3' where cells differ (the experiment's `cell_seeds`), or the checkpoints' seeds
    of an experiment that trains none."""
    per_cell = list(experiment.cell_seeds(results)) if experiment and experiment.cell_seeds else []
    per_cell += [len(runs) for runs in (results.get("checkpoints") or {}).values()
                 if "seeds" not in results and isinstance(runs, list)]
    if per_cell:
        lo, hi = min(per_cell), max(per_cell)
        return str(lo) if lo == hi else f"{lo}-{hi}"
    seeds = results.get("seeds")
    if isinstance(seeds, list):
        return str(len(seeds))
    if isinstance(seeds, int):
        return str(seeds)
    cfg = results.get("config") or {}
    return str(cfg.get("seeds", "-"))


def _wall(results: dict) -> str:
    t = (results.get("timings") or {}).get("total_s") or results.get("wall_s")
    return f"{t / 60:.0f} min" if isinstance(t, (int, float)) else "-"


def _cost(entry: dict) -> float:
    """An experiment's wall seconds, or those of the call that did its work when it reused cached stages."""
    return max(entry["wall_s"], (entry.get("work") or {}).get("wall_s", 0))


def default_call(record: dict) -> dict | None:
    """`reproduce --preset P` as a user runs it (every experiment but those run on request), when the record's
    entries for all its experiments ran at one commit on one machine: {commit, machine, wall_s (their times
    summed), experiments}; else None (their sum is then no one call's time)."""
    runs = record.get("experiments", {})
    names = [e.name for e in catalog.one_command()]
    entries = [runs.get(n) for n in names]
    if not all(entries):
        return None
    machines = [e.get("machine") or record.get("machine") or {} for e in entries]
    commits = {e.get("commit") for e in entries}
    cpus = {m.get("cpu_model") for m in machines}
    if len(commits) != 1 or len(cpus) != 1 or None in commits | cpus:
        return None
    return {"commit": commits.pop(), "machine": machines[0], "wall_s": round(sum(_cost(e) for e in entries), 1),
            "experiments": names}


def _default_command(record: dict) -> str | None:
    """A sentence on the default command's last whole run: the record's entries (default_call), or the one
    experiments.reproduce kept when a later --only call replaced some of them (record["default_command"])."""
    call = default_call(record) or record.get("default_command")
    if not call:
        return None
    m = call["machine"]
    skipped = [e.name for e in catalog.pipeline() if e.on_request]
    return (f"The default command, `python -m experiments.reproduce --preset {record['preset']}` "
            f"({len(call['experiments'])} experiments" + (f"; {', '.join(skipped)} only on request" if skipped else "")
            + f"), last ran whole at `{call['commit'][:12]}` on {m['cpu_model']} ({m['cores']} cores): "
            f"{call['wall_s'] / 60:.0f} min wall, its experiments' times summed.")


def index(rows, root, record: dict | None = None) -> str:
    """The index page of a results tree: every result, what it answers, how it was made and whether it is
    current. record: experiments.reproduce's reproduce.json for this tree (the run's commands and wall times)."""
    record = record or {}
    runs = record.get("experiments", {})
    lines = ["# Published results", "",
             "Generated (do not edit) by `python -m experiments.reproduce` or `python -m experiments.status ROOT "
             "--index`: every result here, what it answers, the command that made it, the commit it ran, its seeds "
             "and wall time, and its state when this page was written (`python -m experiments.status` says it for "
             "today's HEAD).", ""]
    if record:
        # each experiment's cost: its own wall time, or the call that did its work when it reused cached stages
        total = sum(_cost(v) for v in runs.values())
        commits = sorted({r.commit[:12] for r in rows if r.commit})  # what each result recorded it ran
        lines += [f"Made by `python -m experiments.reproduce --preset {record['preset']}` at commit"
                  f"{'s' if len(commits) > 1 else ''} {', '.join(f'`{c}`' for c in commits)}: "
                  f"{total / 60:.0f} min wall in all (the experiments' times summed, a cached one's at the call that "
                  "did its work), load average "
                  f"{record['load_start'][0]:.1f} at the start of the last call and {record['load_end'][0]:.1f} "
                  "at its end.", ""]
        default = _default_command(record)
        if default:
            lines += [default, ""]
        if record.get("ran") and "wall_s" in record:  # the last call alone: one commit, one machine, one clock
            m = record.get("machine") or {}
            lines += [f"The last call ran {', '.join(record['ran'])} at `{record['commit'][:12]}`"
                      + (f" on {m['cpu_model']} ({m['cores']} cores)" if m else "")
                      + f": {record['wall_s'] / 60:.0f} min wall.", ""]
    body = []
    for r in rows:
        e = r.experiment
        rel = r.folder.relative_to(root)
        ran = runs.get(str(rel))
        if ran:  # the one command that re-makes it (its experiment's own command line is in reproduce.json)
            cmd = f"python -m experiments.reproduce --preset {record['preset']} --only {rel}"
            wall = f"{ran['wall_s'] / 60:.1f} min" + ("" if ran.get("fresh", True) else " (cached stages reused")
            if "work" in ran:  # what the stages it reused cost when they ran
                at = ran["work"].get("commit")
                wall += f"; {ran['work']['wall_s'] / 60:.1f} min " + (f"at `{at[:7]}`" if at else "in an earlier call")
            wall += "" if ran.get("fresh", True) else ")"
        else:
            cmd, wall = (f"python -m {e.module}" if e else "-"), _wall(r.results)
        commit = f"`{r.commit[:7]}`" + (" (uncommitted changes)" if r.commit.endswith("-dirty") else "")
        body.append([f"[{rel}]({rel}/)", e.question if e else "-", f"`{cmd}`", commit if r.commit else "-",
                     _seeds(r.results, e), wall, r.state + (f": {_why(r)}" if r.state != "current" else "")])
    lines.append(common.md_table(["result", "answers", "command", "commit", "seeds", "wall", "state"], body))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("root", nargs="?", default=str(common.ROOT / "docs" / "results"),
                    help="a results tree (default: docs/results)")
    ap.add_argument("--stale", action="store_true", help="list only the results that are not current")
    ap.add_argument("--check", action="store_true", help="exit 1 when any result is not current")
    ap.add_argument("--index", action="store_true", help="write ROOT/README.md, the index of every result")
    args = ap.parse_args(argv)
    root = Path(args.root)
    if not root.is_dir():
        ap.error(f"{root}: no such folder")
    rows = check_all(root)
    shown = [r for r in rows if r.state != "current"] if args.stale else rows
    print(table(shown, root))
    counts = {s: sum(r.state == s for r in rows) for s in ("current", "replot", "stale")}
    print(f"\n{len(rows)} results: " + ", ".join(f"{n} {s}" for s, n in counts.items()))
    from experiments import notebooks

    published = root.resolve() == (common.ROOT / "docs" / "results").resolve()
    books = {n.path: notebooks.state(n, changed_since) for n in notebooks.NOTEBOOKS} if published else {}
    if books:  # the notebooks are results too: listed and checked
        print("\n" + common.md_table(["notebook", "state", "why"],
                                     [[p, st, _why(Result(Path(p), None, {}, st, why)) or "-"]
                                      for p, (st, why) in books.items()]))
    if args.index:
        common.write_text(root / "README.md", index(rows, root, common.read_json(root / "reproduce.json")))
        print(f"wrote {root / 'README.md'}")
    behind = counts["current"] < len(rows) or any(st != "current" for st, _ in books.values())
    return 1 if args.check and behind else 0


if __name__ == "__main__":
    import sys

    from ffjax import cli

    sys.exit(cli.run(main))
