"""Files on disk, one way everywhere: atomic writes, checks before work, outputs that never replace an input.

- `atomic_write_bytes/text/json(path, ...)`, `atomic_write(path, fn)`: a temp file beside `path`, fsync, rename,
  fsync of the folder: a kill or a full disk leaves the old file or the new one, never a part. A failure is a
  WriteError naming the file.
- `staged_folder(out)`: a whole output folder written beside `out` and renamed into place when complete.
- `check_writable(folder)`: fail in a second, before any work, when an output cannot be written.
- `check_output(out, reads=..., force=...)`: refuse an output inside (or holding) a folder the command reads
  from, and an existing output unless --force.
- `folder_lock(folder)`: one writer per output folder (an flock the kernel drops when the process dies; the
  file is removed on release).
- `remove_stale_temps(path)`: the temp files of writers of `path` killed mid-write.
- `read_json(path)`: a JSON object, or an error naming the file; `sha256_bytes`, `json_digest` (of `as_json`'s
  form, so the same before writing and after reading) for verifying.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import glob
import hashlib
import json
import os
import shutil
import socket
import sys
import time
from pathlib import Path

from ffjax.errors import CheckpointError, FolderLockedError, WriteError

LOCK_NAME = ".lock"


def atomic_write(path, write, hint: str = "") -> None:
    """write(f) into a temp file beside `path` (binary), then fsync and rename over `path`. `hint` ends the
    WriteError's message (what is still intact, how to continue)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())  # the bytes are on disk before the rename makes them visible
        os.replace(tmp, path)
    except BaseException as e:  # a full disk, or Ctrl-C mid-write: no half-written temp file stays behind
        with contextlib.suppress(OSError):
            tmp.unlink()
        if not isinstance(e, OSError):
            raise
        why = "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))
        raise WriteError(e.errno, f"could not write {path}: {why}" + (f"; {hint}" if hint else "")) from e
    fsync_dir(path.parent)


def remove_stale_temps(path) -> list[Path]:
    """Remove the temp files atomic_write left beside `path` in processes that no longer run (killed mid-write:
    no handler runs on SIGKILL or a power cut); returns them. A running writer's temp file is left alone."""
    path = Path(path)
    prefix = f".{path.name}.tmp"
    removed = []
    for p in path.parent.glob(f"{glob.escape(prefix)}*"):
        pid = p.name[len(prefix):]
        if pid.isascii() and pid.isdigit() and not _running(int(pid)):
            with contextlib.suppress(OSError):
                p.unlink()
                removed.append(p)
    return removed


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def atomic_write_bytes(path, data: bytes, hint: str = "") -> None:
    atomic_write(path, lambda f: f.write(data), hint)


def atomic_write_text(path, text: str, hint: str = "") -> None:
    atomic_write_bytes(path, text.encode(), hint)


def atomic_write_json(path, obj, indent: int | None = 1, hint: str = "") -> None:
    atomic_write_text(path, json.dumps(obj, indent=indent) + "\n", hint)


def fsync_dir(folder) -> None:
    """Make renames in `folder` durable (best effort: some file systems refuse a folder fsync)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def check_writable(folder, need_bytes: int = 0, what: str = "output folder") -> Path:
    """`folder` (absolute, created) when it can be written and has `need_bytes` free; WriteError otherwise."""
    folder = Path(folder).absolute()
    if folder.exists() and not folder.is_dir():  # mkdir would say only "File exists"
        raise WriteError(errno.ENOTDIR, f"{what} {folder} is a file, not a folder")
    probe = folder / f".write_probe{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with open(probe, "wb") as f:
            f.write(b"0" * 4096)
            f.flush()
            os.fsync(f.fileno())
    except OSError as e:
        raise WriteError(e.errno, f"{what} {folder} is not writable: {e.strerror or e}") from e
    finally:
        with contextlib.suppress(OSError):  # e.g. the parent is a file: nothing was created
            probe.unlink()
    free = shutil.disk_usage(folder).free
    if free < need_bytes:
        raise WriteError(errno.ENOSPC, f"{what} {folder} has {free / 2**20:.1f} MiB free; this needs about "
                         f"{need_bytes / 2**20:.1f} MiB. Free some space or choose another --out")
    return folder


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_output(out, reads=(), force: bool = False, flag: str = "--out") -> Path:
    """`out` resolved, unless it would write into what the command reads or over an existing output.

    reads: the inputs (files or folders; None entries are skipped). An output inside an input folder is refused
    whatever `force` says (it would change what is read: a run's files, a folder of frames); so is replacing an
    output that holds an input. An existing output is refused unless `force` (the caller then replaces it). An
    empty folder, or one holding only a lock, is no output yet. FileExistsError naming `flag`."""
    target = Path(out).resolve()
    empty = target.is_dir() and not any(p.name != LOCK_NAME for p in target.iterdir())
    replacing = target.exists() and not empty
    for source in reads:
        if source is None:
            continue
        src = Path(source).resolve()
        if src.is_dir() and _inside(target, src):
            raise FileExistsError(f"{flag} {out} is inside {source}, which this command reads: writing there "
                                  "would change its input; choose an output outside it")
        if _inside(src, target) and (src == target or replacing):
            raise FileExistsError(f"{flag} {out} holds {source}, which this command reads: replacing it would "
                                  "destroy the input; choose another output")
    if replacing and not force:
        raise FileExistsError(f"{flag} {out} already exists; pass --force to replace it, or choose another "
                              f"{flag}")
    return target


@contextlib.contextmanager
def staged_folder(out):
    """Yield an empty temp folder beside `out`; when the block ends without error it replaces `out` (which
    must be replaceable: see check_output), else it is deleted. A reader never sees half a folder."""
    out = Path(out).absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp, old = (out.with_name(f".{out.name}.{tag}{os.getpid()}") for tag in ("tmp", "old"))
    for leftover in (tmp, old):
        shutil.rmtree(leftover, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
        fsync_dir(tmp)
        if out.exists():
            out.rename(old)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)
    fsync_dir(out.parent)


@contextlib.contextmanager
def folder_lock(folder, what: str = "run"):
    """Hold FOLDER/.lock exclusively while the block runs; FolderLockedError naming the holder (pid, host, start
    time, command) when another process holds it. The kernel releases it when the process ends; a clean release
    also removes the file."""
    folder = Path(folder)
    f = _lock(folder, what)
    try:
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}: "
                f"{' '.join(sys.argv)[:200]}\n")
        f.flush()
        yield folder
    finally:
        # unlinked while still locked: a process that opened the file before the unlink gets the lock only on
        # the orphaned inode, sees that the path no longer names it, and locks the path afresh (see _lock)
        with contextlib.suppress(OSError):
            if _same_file(f, folder / LOCK_NAME):
                os.unlink(folder / LOCK_NAME)
        fcntl.flock(f, fcntl.LOCK_UN)
        f.close()


def _lock(folder: Path, what: str):
    """FOLDER/.lock opened and flocked, checked to be the file the path still names (a holder unlinks it when it
    releases: the lock of a file opened just before that guards nothing)."""
    while True:
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
        if _same_file(f, folder / LOCK_NAME):
            return f
        f.close()  # released and unlinked by its holder between our open and our flock: try again


def _same_file(f, path: Path) -> bool:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(f.fileno())
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


def read_json(path, missing_ok: bool = True) -> dict | None:
    """The JSON object in `path`; None when there is no such file and missing_ok; CheckpointError naming the file
    when it is not valid JSON or not an object (truncated, or not written by ffjax)."""
    path = Path(path)
    if not path.is_file():
        if missing_ok:
            return None
        raise FileNotFoundError(f"{path} not found")
    try:
        obj = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise CheckpointError(f"{path} is not valid JSON (truncated, or not written by ffjax): {e}") from e
    if not isinstance(obj, dict):
        raise CheckpointError(f"{path} holds a JSON {type(obj).__name__}, not an object: not written by ffjax")
    return obj


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def as_json(obj):
    """`obj` as JSON reads it back: tuples and sets as lists, numpy scalars and arrays as numbers and lists."""
    return json.loads(json.dumps(obj, default=_plain))


def _plain(x):
    if hasattr(x, "tolist"):
        return x.tolist()
    if isinstance(x, (tuple, set)):
        return list(x)
    raise TypeError(f"{type(x).__name__} is not JSON")


def json_digest(obj) -> str:
    """sha256 of `obj` as canonical JSON (sorted keys): the same for a dict and its JSON round trip."""
    return sha256_bytes(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode())
