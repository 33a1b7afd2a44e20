"""The notebooks as published results: executed on the published results, committed with their outputs, and
checked like any other result (a stale notebook is a stale result).

    python -m experiments.notebooks            # execute every notebook in place (outputs and provenance saved)
    python -m experiments.status               # lists them with the results: current or stale, and why

`python -m experiments.reproduce` runs this after publishing to docs/results/quick. An executed notebook records in
its metadata ("ffjax") the commit it ran at, the digest of its code cells and the digest of every results file it
showed. At HEAD it is current when none of those changed: its cells, the results it shows, and the code it
imports (committed changes since its commit; docstrings, comments and certified same-output simulator changes
do not count, as for every result: experiments.status).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import sys
from pathlib import Path

from experiments import common


@dataclasses.dataclass(frozen=True)
class Notebook:
    path: str  # from the repository root
    shows: tuple  # results files its outputs come from (repository-relative globs)
    code: tuple  # sources whose change makes its outputs stale


NOTEBOOKS = (
    Notebook("notebooks/results.ipynb", ("docs/results/quick/*/results.json",),
             ("experiments/tables.py", "experiments/style.py", "experiments/common.py", "ffjax/results.py")),
    Notebook("notebooks/simulator.ipynb", (), ("ffjax/sim",)),
)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def cells_digest(nb) -> str:
    """The digest of a notebook's code cells (their sources, in order): what produced its outputs."""
    return _sha("\x00".join(c.source for c in nb.cells if c.cell_type == "code").encode())


def shown(notebook: Notebook) -> dict:
    """{results file: sha256} of what the notebook shows, as the files are now."""
    files = sorted(p for pattern in notebook.shows for p in common.ROOT.glob(pattern))
    return {str(p.relative_to(common.ROOT)): _sha(p.read_bytes()) for p in files}


def execute(notebook: Notebook, timeout: int = 900) -> Path:
    """Run every cell in a fresh kernel of this interpreter from the repository root and save the notebook with
    its outputs and provenance in place (atomically: a failed or killed run leaves the old file)."""
    import nbformat
    from nbclient import NotebookClient

    path = common.ROOT / notebook.path
    nb = nbformat.read(path, as_version=4)
    env_path = os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")
    os.environ["PATH"] = env_path  # the kernelspec runs "python": this interpreter's venv first
    NotebookClient(nb, timeout=timeout, kernel_name="python3",
                   resources={"metadata": {"path": str(common.ROOT)}}).execute()
    nb.metadata["ffjax"] = {"commit": common.git_commit(), "cells_sha256": cells_digest(nb),
                            "shows_sha256": shown(notebook)}
    common.write_text(path, nbformat.writes(nb) + "\n")
    return path


def state(notebook: Notebook, changed_since) -> tuple[str, list]:
    """("current" | "stale", why) of a notebook's committed outputs at HEAD. changed_since: experiments.status's
    (the files under paths whose code changed since a commit, None for a commit not in this history)."""
    import nbformat

    nb = nbformat.read(common.ROOT / notebook.path, as_version=4)
    meta = nb.metadata.get("ffjax")
    if not meta:
        return "stale", ["never executed by python -m experiments.notebooks"]
    commit = str(meta.get("commit", ""))
    if commit.endswith("-dirty"):
        return "stale", [f"executed on uncommitted changes to {commit[:7]}"]
    if meta.get("cells_sha256") != cells_digest(nb):
        return "stale", ["its cells changed since they ran"]
    if meta.get("shows_sha256") != shown(notebook):
        return "stale", ["the results it shows changed since it ran"]
    changed = changed_since(commit, notebook.code, certificates=True)
    if changed is None:
        return "stale", [f"commit {commit[:7]} is not in this history"]
    return ("stale", changed) if changed else ("current", [])


def main(argv=None) -> int:
    from ffjax import cli

    ap = argparse.ArgumentParser(prog=common.prog(), description=cli.description(__doc__))
    ap.add_argument("--only", nargs="+", metavar="NOTEBOOK", choices=[Path(n.path).stem for n in NOTEBOOKS],
                    help="Execute only these notebooks (by name: results, simulator).")
    args = ap.parse_args(argv)
    chosen = [n for n in NOTEBOOKS if not args.only or Path(n.path).stem in args.only]
    for n in chosen:
        print(f"executing {n.path}", file=sys.stderr, flush=True)
        execute(n)
    return 0


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
