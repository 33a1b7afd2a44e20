"""One-line errors for every command line tool: `sys.exit(cli.run(main))`.

A fault the user can fix (a missing or foreign file, a bad value, a refused checkpoint or dataset) prints
`error: <message>` and exits 2; a runtime fault (a camera that fails, a full disk) exits 1. The message is
the exception's own, which names the file and what to do. Set FFJAX_DEBUG=1 for the full traceback.
"""

from __future__ import annotations

import logging
import os
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


def run(main, argv=None) -> int:
    """main(argv)'s exit code (0 when it returns no int); known faults become one `error:` line on stderr
    (FFJAX_DEBUG=1: re-raised, and background tracebacks are kept)."""
    if not os.environ.get("FFJAX_DEBUG"):
        _quiet_background_faults()
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
