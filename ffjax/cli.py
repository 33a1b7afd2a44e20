"""One-line errors for every command line tool: `sys.exit(cli.run(main))`.

A fault the user can fix (a missing or foreign file, a bad value, a refused checkpoint or dataset) prints
`error: <message>` and exits 2; a runtime fault (a camera that fails, a full disk) exits 1. The message is
the exception's own, which names the file and what to do. Set FFJAX_DEBUG=1 for the full traceback.
"""

from __future__ import annotations

import os
import sys

USAGE, RUNTIME = 2, 1


def _usage_errors() -> tuple[type, ...]:
    from ffjax.convert.reader import UnsafePickleError
    from ffjax.data.validate import DataError
    from ffjax.train.checkpoint import CheckpointError

    # CheckpointWriteError (a full or read-only disk) subclasses OSError: runtime, not usage
    return (FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError, DataError, CheckpointError,
            UnsafePickleError, ValueError, KeyError)


def run(main, argv=None) -> int:
    """main(argv)'s exit code (0 when it returns no int); known faults become one `error:` line on stderr
    (FFJAX_DEBUG=1: re-raised)."""
    try:
        rc = main(argv)
        return rc if isinstance(rc, int) else 0
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - sorted below; anything unexpected still shows its traceback
        if os.environ.get("FFJAX_DEBUG"):
            raise
        code = USAGE if isinstance(e, _usage_errors()) else RUNTIME if isinstance(e, (OSError, RuntimeError)) \
            else None
        if code is None:
            raise
        msg = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"error: {msg}", file=sys.stderr)
        return code
