"""Read PyTorch weight files without importing torch.

`.safetensors` goes through the safetensors numpy API. `.pth` / `.pth.tar` / `.pt` files written by
`torch.save` (zip format, torch >= 1.6) are zip archives holding one pickle (`*/data.pkl`) whose tensors
point at raw storages (`*/data/<key>`). They are read with an allow-list unpickler: only tensor-rebuild,
storage-type, OrderedDict and primitive globals may appear, the equivalent of
`torch.load(weights_only=True)`; anything else raises `UnsafePickleError` naming the file and the global.
Tensors stay lazy (`TensorRef`) until asked for, so optimizer state in a training checkpoint costs nothing.
"""

from __future__ import annotations

import collections
import io
import pickle
import zipfile
from pathlib import Path

import ml_dtypes
import numpy as np

from ffjax.errors import UnsafePickleError

_STORAGE_DTYPES = {
    "DoubleStorage": np.float64,
    "FloatStorage": np.float32,
    "HalfStorage": np.float16,
    "BFloat16Storage": ml_dtypes.bfloat16,
    "LongStorage": np.int64,
    "IntStorage": np.int32,
    "ShortStorage": np.int16,
    "CharStorage": np.int8,
    "ByteStorage": np.uint8,
    "BoolStorage": np.bool_,
    "UntypedStorage": np.uint8,
}
_TORCH_DTYPES = {
    "float64": np.float64,
    "double": np.float64,
    "float32": np.float32,
    "float": np.float32,
    "float16": np.float16,
    "half": np.float16,
    "bfloat16": ml_dtypes.bfloat16,
    "int64": np.int64,
    "long": np.int64,
    "int32": np.int32,
    "int": np.int32,
    "int16": np.int16,
    "int8": np.int8,
    "uint8": np.uint8,
    "bool": np.bool_,
}


class MissingExtraError(ModuleNotFoundError, RuntimeError):
    """An optional dependency is not installed. A ModuleNotFoundError to Python; a RuntimeError too, so every
    command line tool (ffjax.cli) prints it as one `error:` line (exit 1) instead of a traceback."""


class _ViewError(ValueError):
    """A tensor's size, stride or offset does not fit its storage or file (state_dict adds file and name)."""


class _StorageType:
    def __init__(self, name: str, dtype):
        self.name, self.dtype = name, np.dtype(dtype)


class _Storage:
    """A lazily read storage: raw bytes of one zip entry, viewed as `dtype`."""

    def __init__(self, archive: _Archive, key: str, dtype: np.dtype):
        self.archive, self.key, self.dtype = archive, key, dtype
        self._array = None

    def file_size(self) -> int:
        return self.archive.path.stat().st_size

    def array(self) -> np.ndarray:
        if self._array is None:
            self._array = self.archive.storage_bytes(self.key, self.dtype)
        return self._array


class TensorRef:
    """A tensor in a checkpoint, not yet read: `.shape`, `.dtype`, `.numpy()`."""

    def __init__(self, storage: _Storage, offset: int, size: tuple, stride: tuple, dtype=None):
        self.storage, self.offset = storage, int(offset)
        self.shape, self.stride = tuple(int(s) for s in size), tuple(int(s) for s in stride)
        self.dtype = np.dtype(dtype) if dtype is not None else storage.dtype

    def numpy(self) -> np.ndarray:
        self._check_size()
        flat = self.storage.array()
        if self.dtype != flat.dtype:  # a v3 rebuild over an untyped (byte) storage
            flat = flat.view(self.dtype)
        if not self.shape:
            return np.array(flat[self.offset])
        # as_strided does not bounds-check: a crafted file must not make it read past the storage
        last = self.offset + sum((n - 1) * s for n, s in zip(self.shape, self.stride) if n > 0)
        if min(self.stride, default=0) < 0 or self.offset < 0 or (0 not in self.shape and last >= flat.size):
            raise _ViewError(f"tensor {self.shape} stride {self.stride} offset {self.offset} exceeds its storage")
        if 0 in self.shape:
            return np.zeros(self.shape, self.dtype)
        itemsize = flat.dtype.itemsize
        view = np.lib.stride_tricks.as_strided(
            flat[self.offset :], shape=self.shape, strides=tuple(s * itemsize for s in self.stride)
        )
        return np.array(view)  # a contiguous copy; strided views of shared storages must not alias

    def _check_size(self) -> None:
        """Refuse, before allocating, a tensor larger than its whole file: stride-0 views over a tiny storage
        (a 500-byte file declaring 10^9 elements) would otherwise be copied out to gigabytes."""
        nbytes, on_disk = int(np.prod(self.shape, dtype=np.int64)) * self.dtype.itemsize, self.storage.file_size()
        if nbytes > on_disk:
            raise _ViewError(f"tensor {self.shape} {self.dtype} declares {nbytes:,} bytes, more than the whole file "
                             f"({on_disk:,} bytes); corrupt or crafted, refusing to allocate it")

    def __repr__(self):
        return f"TensorRef(shape={self.shape}, dtype={self.dtype})"


def _rebuild_tensor_v2(storage, offset, size, stride, requires_grad=False, hooks=None, metadata=None):
    return TensorRef(storage, offset, size, stride)


def _rebuild_tensor_v3(storage, offset, size, stride, requires_grad, hooks, dtype, metadata=None):
    return TensorRef(storage, offset, size, stride, dtype=dtype)


def _rebuild_parameter(data, requires_grad=False, hooks=None, state=None):
    return data


def _rebuild_from_type_v2(func, new_type, args, state):
    return func(*args)


def _encode(text, encoding="latin1"):
    # protocol-2 pickles store bytes as latin1 text (`_codecs.encode`); only that use is allowed
    if encoding not in ("latin1", "latin-1"):
        raise UnsafePickleError(f"_codecs.encode with encoding {encoding!r} is not allowed")
    return text.encode(encoding)


def _np_scalar(dtype, data):
    return np.frombuffer(data, dtype=dtype)[0]


def _np_dtype(name, align=False, copy=False):
    return np.dtype(name)


def _tensor_type(*args, **kwargs):
    raise UnsafePickleError("constructing torch.Tensor / nn.Parameter objects directly is not allowed")


_ALLOWED = {
    ("collections", "OrderedDict"): collections.OrderedDict,
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor_v2,
    ("torch._utils", "_rebuild_tensor_v3"): _rebuild_tensor_v3,
    ("torch._utils", "_rebuild_parameter"): _rebuild_parameter,
    ("torch._utils", "_rebuild_parameter_with_state"): _rebuild_parameter,
    ("torch._tensor", "_rebuild_from_type_v2"): _rebuild_from_type_v2,
    ("torch", "Tensor"): _tensor_type,
    ("torch.nn.parameter", "Parameter"): _tensor_type,
    ("torch", "Size"): tuple,
    ("torch", "device"): str,
    ("builtins", "set"): set,
    ("builtins", "frozenset"): frozenset,
    ("builtins", "slice"): slice,
    ("_codecs", "encode"): _encode,
    ("numpy.core.multiarray", "scalar"): _np_scalar,
    ("numpy._core.multiarray", "scalar"): _np_scalar,
    ("numpy", "dtype"): _np_dtype,
}


class _Archive:
    """One torch zip checkpoint: its pickle, storages and byte order."""

    def __init__(self, path: Path):
        self.path = path
        self.zip = zipfile.ZipFile(path)
        pickles = [n for n in self.zip.namelist() if n.endswith("data.pkl")]
        if len(pickles) != 1:
            raise ValueError(f"{path}: expected one data.pkl in the torch zip archive, found {pickles}")
        self.prefix = pickles[0][: -len("data.pkl")]
        names = set(self.zip.namelist())
        order = self.prefix + "byteorder"
        self.big_endian = order in names and self.zip.read(order).decode().strip() == "big"
        self.storages: dict[str, _Storage] = {}

    def storage_bytes(self, key: str, dtype: np.dtype) -> np.ndarray:
        name = f"{self.prefix}data/{key}"
        try:
            declared, on_disk = self.zip.getinfo(name).file_size, self.path.stat().st_size
        except KeyError:
            declared, on_disk = 0, 1
        if declared > on_disk:  # torch stores storages uncompressed: more bytes than the file is a zip bomb
            raise ValueError(f"{self.path}: tensor storage data/{key} declares {declared:,} bytes, more than the "
                             f"whole file ({on_disk:,} bytes); corrupt or crafted, refusing to inflate it")
        try:
            raw = self.zip.read(name)
        except (KeyError, zipfile.BadZipFile, EOFError, OSError) as e:
            raise ValueError(f"{self.path}: tensor storage data/{key} is missing or unreadable ({e}); the file is "
                             "partial or corrupt (an interrupted download or copy?)") from e
        array = np.frombuffer(raw, dtype=dtype.newbyteorder(">") if self.big_endian else dtype)
        return array.astype(dtype) if self.big_endian else array

    def storage(self, key: str, dtype: np.dtype) -> _Storage:
        if key not in self.storages:
            self.storages[key] = _Storage(self, key, dtype)
        return self.storages[key]


class _SafeUnpickler(pickle.Unpickler):
    def __init__(self, data: bytes, archive: _Archive):
        super().__init__(io.BytesIO(data))
        self.archive = archive

    def find_class(self, module, name):
        if module == "torch" and name in _STORAGE_DTYPES:
            return _StorageType(name, _STORAGE_DTYPES[name])
        if module == "torch" and name in _TORCH_DTYPES:
            return np.dtype(_TORCH_DTYPES[name])
        if (module, name) in _ALLOWED:
            return _ALLOWED[(module, name)]
        raise UnsafePickleError(
            f"{self.archive.path}: refusing to unpickle global '{module}.{name}' (only tensors, storages, "
            "OrderedDict and primitive values are allowed, as torch.load(weights_only=True))"
        )

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and pid and pid[0] == "storage"):
            raise UnsafePickleError(f"{self.archive.path}: unexpected persistent id {pid!r}")
        _, storage_type, key, _location, _numel = pid
        if isinstance(storage_type, np.dtype):  # newer torch may name a dtype here
            dtype = storage_type
        elif isinstance(storage_type, _StorageType):
            dtype = storage_type.dtype
        else:
            raise UnsafePickleError(f"{self.archive.path}: bad storage type {storage_type!r}")
        return self.archive.storage(str(key), dtype)


def load_torch(path) -> object:
    """Unpickle a `torch.save` zip file safely; tensors come back as lazy `TensorRef`s."""
    path = Path(path)
    if not zipfile.is_zipfile(path):
        with open(path, "rb") as f:
            head = f.read(4)
        if head.startswith(b"PK"):
            raise ValueError(f"{path}: a truncated or corrupt zip (partial download or copy?); fetch it again")
        raise ValueError(
            f"{path}: not a zip-format torch checkpoint. Legacy (torch < 1.6) pickles are not read, since "
            "that would need unrestricted unpickling; re-save it with a current torch (torch.save) or as "
            ".safetensors"
        )
    try:
        archive = _Archive(path)
        data = archive.zip.read(archive.prefix + "data.pkl")
    except (zipfile.BadZipFile, EOFError, OSError) as e:
        raise ValueError(f"{path}: a corrupt torch zip archive ({e}); fetch or save it again") from e
    try:
        return _SafeUnpickler(data, archive).load()
    except (UnsafePickleError, ValueError):
        raise
    except (pickle.UnpicklingError, EOFError, AttributeError, IndexError, TypeError) as e:
        raise ValueError(f"{path}: its data.pkl does not unpickle as a state dict ({type(e).__name__}: {e}); "
                         "partial, corrupt or not a torch weight file") from e


def load(path) -> object:
    """Load a weight file: `.safetensors` -> dict of arrays; torch files -> the unpickled object."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.suffix == ".safetensors":
        try:
            from safetensors.numpy import load_file
        except ModuleNotFoundError:
            raise MissingExtraError(f"{path}: reading .safetensors needs the optional extra ffjax[weights]: "
                                    "pip install -e \".[weights]\" (or pip install safetensors)",
                                    name="safetensors") from None
        try:
            return load_file(str(path))
        except Exception as e:  # safetensors raises its own SafetensorError on truncated headers/data
            raise ValueError(f"{path}: not a readable .safetensors file ({e}); partial or corrupt?") from e
    return load_torch(path)


_NESTING_KEYS = ("state_dict", "model_state_dict", "model", "module", "teacher", "student", "net")
_PREFIXES = ("module.", "_orig_mod.")


def _is_tensor(x) -> bool:
    return isinstance(x, TensorRef | np.ndarray)


def _flatten(obj, prefix: str, out: dict):
    for key, value in obj.items():
        name = f"{prefix}{key}"
        if _is_tensor(value):
            out[name] = value
        elif isinstance(value, dict):
            _flatten(value, name + ".", out)


def state_dict(obj, path="<checkpoint>") -> dict[str, np.ndarray]:
    """The model weights in a loaded checkpoint as a flat {torch name: array} dict.

    Unwraps the usual nesting ({"state_dict": ...}, {"model": ...}, DINO's {"teacher": ...}) and strips
    DataParallel / torch.compile prefixes ("module.", "_orig_mod.").
    """
    while isinstance(obj, dict) and not any(_is_tensor(v) for v in obj.values()):
        inner = next((obj[k] for k in _NESTING_KEYS if isinstance(obj.get(k), dict)), None)
        if inner is None:
            raise ValueError(f"{path}: no state dict found; top-level keys are {sorted(map(str, obj))}")
        obj = inner
    if not isinstance(obj, dict):
        raise ValueError(f"{path}: expected a dict of tensors, got {type(obj).__name__}")
    flat: dict = {}
    _flatten(obj, "", flat)
    out = {}
    for name, value in flat.items():
        while name.startswith(_PREFIXES):
            name = name.split(".", 1)[1]
        try:
            out[name] = value.numpy() if isinstance(value, TensorRef) else np.asarray(value)
        except _ViewError as e:  # the view's checks know neither the file nor the tensor's name
            raise ValueError(f"{path}: {name}: {e}") from e
    return out


def read_state_dict(path) -> dict[str, np.ndarray]:
    """`load` + `state_dict`: a weight file as a flat {torch name: numpy array} dict."""
    return state_dict(load(path), path)
