"""One writer per output folder: `with folder_lock(run_dir, "training run"): ...`.

An exclusive flock on FOLDER/.lock, held while the writer runs and released by the kernel when the process
ends (a kill leaves no stale lock). A second writer is refused at once with FolderLockedError naming the
holder (pid, host, start time, command), instead of interleaving logs or mixing one run's model.json with
another's weights.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import sys
import time
from pathlib import Path

LOCK_NAME = ".lock"


class FolderLockedError(RuntimeError):
    """The output folder is being written by another process."""


@contextlib.contextmanager
def folder_lock(folder, what: str = "run"):
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    f = open(folder / LOCK_NAME, "a+")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.seek(0)
        holder = f.read().strip() or "another process"
        f.close()
        raise FolderLockedError(f"{folder} is in use by another {what} ({holder}); wait for it to finish or "
                                "choose another output folder") from None
    try:
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}: "
                f"{' '.join(sys.argv)[:200]}\n")
        f.flush()
        yield folder
    finally:
        with contextlib.suppress(OSError):
            f.truncate(0)
        fcntl.flock(f, fcntl.LOCK_UN)
        f.close()
