"""Execute a notebook as a user's Jupyter would: a fresh kernel of this interpreter, in a given folder."""

import os
import sys
from pathlib import Path

import nbformat
from nbclient import NotebookClient


def execute(path: Path, cwd: Path, monkeypatch) -> None:
    # the kernelspec runs "python": put this interpreter's venv first so the kernel imports ffjax
    monkeypatch.setenv("PATH", os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", ""))
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(cwd)}}).execute()
