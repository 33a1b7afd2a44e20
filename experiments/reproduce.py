"""Bring every published result of a preset up to date from the current commit, in one command.

    python -m experiments.reproduce --preset {smoke,quick,full} [--only NAME ...] [--work DIR] [--publish DIR]
                                    [--no-publish] [--data DIR] [--quiet] [--workers N]

Runs each experiment of experiments.catalog's pipeline in order (the ablation with 3 seeds, the loss sweep, the
speed/accuracy chart, stability, downstream, both benchmarks; those marked on request, such as pattern_share, only
when --only names them), each into WORK/<name> (default WORK:
results/reproduce-<preset>); an experiment that reads trained runs reads the ablation's (--ablation
WORK/ablation), so nothing is trained twice, and every stage is cached: a killed or repeated call continues
where it stopped; WORK/reproduce.json records each experiment's wall time as it finishes, so a kill loses none
that finished. Then each result folder, without its trained runs, is copied to PUBLISH/<name> (default:
docs/results/<preset>; --no-publish leaves docs alone), with reproduce.json (commit, preset, each experiment's
wall time and the load) and the index page (experiments.status --index); publishing to docs/results/quick also
executes the notebooks on it (experiments.notebooks), then `python -m experiments.doc_tables` brings README and
docs to the new numbers.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

import configs
from experiments import catalog, common, mappings, status

# published beside the tables: everything an experiment writes except its trained runs and its caches
_NOT_PUBLISHED = ("runs", "checkpoints", "cache", "frames")


def argv_for(exp: catalog.Experiment, preset: str, work: Path, quiet: bool, data: str | None = None,
             workers: int | None = None) -> list[str]:
    """The command line of one experiment in the pipeline, with the common flags it takes."""
    given = {"--quiet": [] if quiet else None, "--data": [str(data)] if data else None,
             "--workers": [str(workers)] if workers else None}
    extra = [a for flag in exp.flags if given[flag] is not None for a in (flag, *given[flag])]
    return [*exp.args(preset, work), "--out", str(work / exp.name), *extra]


def run_one(exp: catalog.Experiment, argv: list[str]) -> float:
    """Run an experiment's main(argv) in this process; its wall seconds."""
    main = exp.main()
    t0 = time.perf_counter()
    main(argv)
    return round(time.perf_counter() - t0, 1)


def publish(src: Path, dst: Path) -> None:
    """Copy a result folder without its trained runs and caches, replacing what dst held."""
    tmp = dst.with_name(dst.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    shutil.copytree(src, tmp, ignore=shutil.ignore_patterns(*_NOT_PUBLISHED, "*.partial", "stage.json"))
    for folder in sorted((p for p in tmp.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
        if not any(folder.iterdir()):  # held only runs or caches: nothing of it is published
            folder.rmdir()
    if dst.exists():
        shutil.rmtree(dst)
    tmp.rename(dst)


def merged_record(path: Path, record: dict) -> dict:
    """reproduce.json at path updated by this call's record: an --only call replaces its experiments' entries
    (each keeps the commit and the machine it ran on) and leaves the others'. An entry that reused cached stages
    keeps, as "work", the wall time and commit of the call that did the most work (a cached re-run's seconds are
    not its cost). "default_command" keeps the default command's last whole run (status.default_call)."""
    previous = common.read_json(path) or {}
    entries = dict(previous.get("experiments", {}))
    if previous.get("machine"):  # the top-level machine is the last call's: earlier entries keep their own
        entries = {n: e if "machine" in e or e.get("commit") != previous.get("commit")
                   else {**e, "machine": previous["machine"]} for n, e in entries.items()}
    for name, entry in record["experiments"].items():
        old = entries.get(name)
        if old and not entry.get("fresh", True):
            done = old.get("work") or {"wall_s": old["wall_s"], "commit": old.get("commit")}  # None: not recorded
            if done["wall_s"] > entry["wall_s"]:
                entry = {**entry, "work": done}
        entries[name] = entry
    merged = {**previous, **record, "experiments": entries}
    # the default command's last whole run, kept when an --only call replaces some of its entries (status.index)
    whole = status.default_call(merged) or status.default_call(previous) or previous.get("default_command")
    return {**merged, "default_command": whole} if whole else merged


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("--preset", default="quick", choices=configs.PRESETS,
                    help="the preset whose published results are brought up to date (default: quick)")
    ap.add_argument("--only", nargs="+", default=None, metavar="NAME",
                    help=f"a subset of the pipeline ({', '.join(e.name for e in catalog.pipeline())}); without it, "
                         f"all but {', '.join(e.name for e in catalog.pipeline() if e.on_request) or 'none'}")
    ap.add_argument("--work", default=None, help="where the experiments run and keep their trained runs "
                                                  "(default: results/reproduce-<preset>)")
    ap.add_argument("--publish", default=None, help="where the results are published (default: docs/results/<preset>)")
    ap.add_argument("--no-publish", action="store_true", help="run only; leave the published results as they are")
    ap.add_argument("--data", default=None, help="dataset folder (default: data/<preset>, made if missing)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    ap.add_argument("--workers", type=int, default=None, metavar="N",
                    help="training runs at once in the experiments that train (default: each one's, 2 on a CPU "
                         "with 2 or more cores)")
    args = ap.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        ap.error("--workers must be at least 1")
    chosen = catalog.one_command()
    if args.only:
        names = {e.name for e in catalog.pipeline()}
        for n in args.only:
            if n not in names:
                ap.error(f"--only {n}: not in the pipeline ({', '.join(sorted(names))})")
        chosen = tuple(e for e in catalog.pipeline() if e.name in args.only)
    work = Path(args.work or common.ROOT / "results" / f"reproduce-{args.preset}").absolute()
    dest = None if args.no_publish else Path(args.publish or common.ROOT / "docs" / "results" / args.preset)
    from ffjax import cli
    from ffjax.sim import dataset

    cli.check_out(ap, work, "--work")
    if dest is not None:
        cli.check_out(ap, dest, "--publish")
    commit = common.git_commit()
    print(f"{common.prog() or 'reproduce'}: preset {args.preset}, commit {commit[:12]}, "
          f"{len(chosen)} experiments into {work}", file=sys.stderr)
    if commit.endswith("-dirty"):  # results published by an earlier call count: commit them before the next
        print("warning: tracked files differ from the commit (published results too): every result of this run "
              "records it ran on uncommitted changes, which experiments.status calls stale. Commit first.",
              file=sys.stderr)
    # one dataset for the whole pipeline: the ablation makes it, the simulator's benchmark reads its time
    data = Path(args.data or dataset.default_root(args.preset)).absolute()
    record = {"preset": args.preset, "commit": commit, "machine": common.machine(),
              "ran": [e.name for e in chosen], "load_start": list(os.getloadavg()), "experiments": {}}
    t0 = time.perf_counter()
    for exp in chosen:
        line = argv_for(exp, args.preset, work, args.quiet, data, args.workers)
        print(f"[reproduce] {exp.name}: python -m {exp.module} {' '.join(line)}", file=sys.stderr, flush=True)
        fresh = not (work / exp.name).exists()  # else cached stages may be reused: its wall time is not its cost
        record["experiments"][exp.name] = {"argv": line, "wall_s": run_one(exp, line), "fresh": fresh,
                                           "commit": commit, "machine": record["machine"],
                                           "load_after": list(os.getloadavg())}
        # recorded as each finishes: a kill or a crash later in a pipeline of hours keeps what it measured
        done = {**record, "experiments": {exp.name: record["experiments"][exp.name]}}
        common.write_json(work / "reproduce.json", merged_record(work / "reproduce.json", done))
        if mappings.release_if_crowded():  # the experiments share this process; the next compiles afresh
            print(f"[reproduce] {exp.name}: released jax's compiled programs (memory mappings past half the "
                  f"kernel's limit of {mappings.limit():,})", file=sys.stderr, flush=True)
    record["wall_s"] = round(time.perf_counter() - t0, 1)
    record["load_end"] = list(os.getloadavg())
    common.write_json(work / "reproduce.json", merged_record(work / "reproduce.json", record))
    if dest is not None:
        dest.mkdir(parents=True, exist_ok=True)
        for exp in chosen:
            publish(work / exp.name, dest / exp.name)
        merged = merged_record(dest / "reproduce.json", record)
        common.write_json(dest / "reproduce.json", merged)
        rows = status.check_all(dest)
        common.write_text(dest / "README.md", status.index(rows, dest, merged))
        print(f"published {len(chosen)} results to {dest} (index: {dest / 'README.md'})", file=sys.stderr)
        if dest.resolve() == (common.ROOT / "docs" / "results" / "quick").resolve():
            from experiments import notebooks  # they show this tree: their outputs are results of it too

            for book in notebooks.NOTEBOOKS:
                print(f"[reproduce] executing {book.path}", file=sys.stderr, flush=True)
                notebooks.execute(book)
    return record


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
