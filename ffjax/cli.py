"""One-line errors for every command line tool: `sys.exit(cli.run(main))`.

A fault the user can fix (a missing or foreign file, a bad value, a refused checkpoint or dataset) prints
`error: <message>` and exits 2; a runtime fault (a camera that fails, a full disk) exits 1. The message is
the exception's own, which names the file and what to do. Set FFJAX_DEBUG=1 for the full traceback.

argparse types (`integer(1)`, `number(0)`, `fraction`, `frame_size`) refuse a bad flag value at parse time,
before any work, naming the flag and the form expected.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import re
import signal
import sys
import threading

from ffjax.errors import USAGE_ERRORS, WriteError
from ffjax.files import check_writable

USAGE, RUNTIME = 2, 1
_REPORTED = threading.Event()  # set once main() has failed: later orbax records only echo that failure


def _from_orbax(text: str) -> bool:
    return "orbax" in text or "Event loop is closed" in text


class _OneLineBackgroundErrors(logging.Filter):
    """orbax logs a failed background write from each of its threads with a full traceback, and asyncio adds
    one for every pending write task: one full disk printed 900-2,000 lines above the one error that matters
    (the WriteError that run() prints). Keep orbax's lines to one line each; drop asyncio's repeats."""

    def filter(self, record: logging.LogRecord) -> bool:
        if _REPORTED.is_set():  # main() has failed: orbax threads still failing only echo it
            return False
        if record.name == "asyncio":
            return not _from_orbax(record.getMessage() + repr(record.exc_info and record.exc_info[1]))
        if record.exc_info and "orbax" in record.pathname:
            record.msg, record.args = record.getMessage().splitlines()[0][:300], ()
            record.exc_info = record.exc_text = None
        return True


def _quiet_background_faults() -> None:
    """Silence the echoes of one checkpoint-write failure in orbax's threads and coroutines (see
    _OneLineBackgroundErrors); a coroutine collected at exit or a TensorStore callback into a closed event loop
    says nothing new either. Everything else is reported as before."""
    flt = _OneLineBackgroundErrors()
    for name in ("absl", "asyncio"):
        if not any(isinstance(f, _OneLineBackgroundErrors) for f in logging.getLogger(name).filters):
            logging.getLogger(name).addFilter(flt)
    unraisable, thread_hook = sys.unraisablehook, threading.excepthook

    def quiet_unraisable(u):
        code = getattr(u.object, "cr_code", None)
        if not _from_orbax(f"{getattr(code, 'co_filename', '')} {u.exc_value!r}"):
            unraisable(u)

    def quiet_thread(args):
        if not (isinstance(args.exc_value, RuntimeError) and "Event loop is closed" in str(args.exc_value)):
            thread_hook(args)

    sys.unraisablehook, threading.excepthook = quiet_unraisable, quiet_thread


def description(doc: str | None) -> str:
    """A module docstring's whole first paragraph on one line: the `description=` of its `--help`, whose first
    sentence a docstring's line break would otherwise cut (`doc.splitlines()[0]`). One line already is itself."""
    first = re.split(r"\n[ \t]*\n", (doc or "").strip(), maxsplit=1)[0]
    return " ".join(first.split())


# --which of the tools that load a checkpoint (ffjax.store.load)
WHICH_HELP = ("which weights of a training run to load: best (its lowest validation loss, the default) or latest "
              "(its last saved step); a calibrated or converted folder holds one set and ignores it")


def check_out(parser, folder, flag: str = "--out"):
    """`folder` (absolute) once it is created and writable; otherwise a usage error naming `flag` (exit 2), before
    any work: an output under a file or on a read-only disk fails in a second, not after the run."""
    try:
        return check_writable(folder)
    except WriteError as e:
        parser.error(f"{flag}: {e}")


def fail(message, code: int = RUNTIME) -> int:
    """Print `error: message` as the run's last line and return `code`: for tools that catch their own errors.
    Later records of orbax's background threads (echoes of the same failure) are dropped."""
    _REPORTED.set()
    print(f"error: {message}", file=sys.stderr, flush=True)
    return code


class BadValue(argparse.ArgumentTypeError, ValueError):
    """A flag's value outside its form or range. Raised by the argparse types below, argparse reports it as
    `argument --flag: <message>` (exit 2); elsewhere (a library call) it is a ValueError."""


def integer(minimum: int, meaning: str = ""):
    """argparse type: an int >= minimum; `meaning` says what the smallest value does (e.g. "0: never")."""
    def parse(text: str) -> int:
        value = int(text) if re.fullmatch(r"\s*[-+]?[0-9]+\s*", text) else None  # int() also takes "1_0"
        if value is None or value < minimum:
            raise BadValue(f"expected an integer >= {minimum}{f' ({meaning})' if meaning else ''}, got {text!r}")
        return value

    return parse


def number(minimum: float = 0.0, inclusive: bool = False):
    """argparse type: a finite float > minimum (>= with `inclusive`); nan and inf are refused."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value < minimum or (value == minimum and not inclusive):
            raise BadValue(f"expected a finite number {'>=' if inclusive else '>'} {minimum:g}, got {text!r}")
        return value

    return parse


def fraction(text: str) -> float:
    """argparse type: a float in [0, 1)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 <= value < 1:  # also refuses nan
        raise BadValue(f"expected a fraction in [0, 1), got {text!r}")
    return value


def frame_size(text: str) -> tuple[int, int]:
    """argparse type: "HxW" (both >= 1) as (H, W)."""
    m = re.fullmatch(r"\s*([0-9]+)\s*[xX]\s*([0-9]+)\s*", str(text))
    if not m or min(int(m[1]), int(m[2])) < 1:
        raise BadValue(f"expected HxW such as 240x320 (height x width, both >= 1), got {text!r}")
    return int(m[1]), int(m[2])


@contextlib.contextmanager
def sigterm_as_interrupt():
    """While the block runs, SIGTERM (kill, a supervisor stopping the tool) raises KeyboardInterrupt like Ctrl-C,
    so the cleanup a Ctrl-C runs (temp files removed, a video finalised) runs too; the default action would end
    the process at once. Only in the main thread (signal handlers can be set nowhere else)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def run(main, argv=None) -> int:
    """main(argv)'s exit code (0 when it returns no int); known faults become one `error:` line on stderr
    (FFJAX_DEBUG=1: re-raised, and background tracebacks are kept)."""
    if not os.environ.get("FFJAX_DEBUG"):
        _quiet_background_faults()
    from ffjax import compile_cache  # here, not at import: modules that only parse flags stay free of jax

    compile_cache.enable()  # every command loads what an earlier one compiled on this machine
    _REPORTED.clear()
    try:
        rc = main(argv)
        return rc if isinstance(rc, int) else 0
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - sorted below; anything unexpected still shows its traceback
        if os.environ.get("FFJAX_DEBUG"):
            raise
        _REPORTED.set()  # from here on, background records only echo this failure: the error line stays last
        code = USAGE if isinstance(e, USAGE_ERRORS) else RUNTIME if isinstance(e, (OSError, RuntimeError)) \
            else None
        if code is None:
            raise
        return fail(e.args[0] if isinstance(e, KeyError) and e.args else e, code)
