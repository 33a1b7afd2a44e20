"""The errors ffjax raises for faults a user can act on; every message names the file (and row, key or tensor).

`ffjax.cli` sorts them into exit codes: a usage fault (exit 2: a bad or foreign file, a bad value) or a runtime
fault (exit 1: a full disk, a folder in use). This module imports nothing, so every layer can raise them.
"""

from __future__ import annotations

import pickle


class CheckpointError(ValueError):
    """A saved model or artifact that cannot be used: missing, partial, corrupt, edited after it was written,
    or written for another model / not by ffjax (training runs, bundles, converted weights, exports)."""


class DataError(ValueError):
    """A split on disk is malformed; the message names the file (and row) at fault."""


class UnsafePickleError(pickle.UnpicklingError):
    """A checkpoint's pickle references a global outside the allow-list."""


class WriteError(OSError):
    """A file could not be written (disk full, no permission); what was written before is intact."""

    def __str__(self) -> str:  # the message alone, without OSError's "[Errno 28]" prefix
        return self.strerror or super().__str__()


class FolderLockedError(RuntimeError):
    """The output folder is being written by another process."""


# exit 2: the user gave something that can never work; CheckpointError, DataError, ConfigError (configs) and
# ConversionError (convert) are ValueErrors. WriteError and FolderLockedError are runtime faults (exit 1).
USAGE_ERRORS = (FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError, ValueError, KeyError,
                UnsafePickleError)
