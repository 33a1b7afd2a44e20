"""Export a predictor as one serialized `jax.export` function: raw frames in, forces out.

    python -m ffjax.export --checkpoint RUN --out force.jaxexport [--batch 1] [--platforms cpu,cuda] [--force]

writes `force.jaxexport` (StableHLO with the weights baked in) and `force.jaxexport.json` (frame size,
channel order, force range, input/output description, the export's sha256; written last). An existing export
is replaced only with --force, and never inside the checkpoint folder it is made from. --platforms are jax's
built-in lowering targets (cpu, cuda, rocm, tpu); the export runs only on those. A killed export leaves no temp
file behind (Ctrl-C and SIGTERM remove it; after a SIGKILL the next export to the same --out does).

The whole preprocessing is inside the function: background subtraction (clip(img - bg + 127)), pad to
square, resize, /255, normalization. The resize is written as two small matrix products whose weights are taken
from cv2 at export time (the INTER_AREA / INTER_LINEAR kernels `ffjax.data.preprocess_image` uses), so the
exported function matches the Predictor to float32 rounding (tests check |difference| < 1e-4 N). --batch 0
exports a symbolic batch size.

Running it needs only jax (no ffjax, flax or training code):

    import json, numpy as np
    from jax import export
    fn = export.deserialize(open("force.jaxexport", "rb").read())
    info = json.load(open("force.jaxexport.json"))          # frame_size, channels ("RGB"), force range
    forces = np.asarray(fn.call(frames, background))        # (B, H, W, 3), (H, W, 3) uint8 RGB -> (B, 3) N

(or `ffjax.export.load(path)(frames, background)`, which also verifies the file against the sha256 in its
sidecar (an export without one loads with a warning that it is unverified), checks shapes and flags out-of-range
and NaN/inf forces like `inference.Predictor.predict`).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from ffjax import cli, inference
from ffjax.errors import CheckpointError
from ffjax.files import atomic_write_bytes, atomic_write_json, check_output, read_json, remove_stale_temps, sha256_bytes
from ffjax.store.checksums import UnverifiedWarning, warn_unverified

FORMAT = "ffjax.export/1"
PLATFORMS = ("cpu", "cuda", "rocm", "tpu")  # jax.export's built-in lowering platforms


def resize_matrix(side: int, size: int) -> np.ndarray:
    """(size, side) matrix R with R @ v == cv2.resize of v from side to size samples, using the kernel
    `ffjax.data.preprocess` picks (INTER_AREA when shrinking, INTER_LINEAR when enlarging). Both are
    separable, so a square resize is R @ X @ R.T."""
    if side == size:
        return np.eye(size, dtype=np.float32)
    interp = cv2.INTER_AREA if side > size else cv2.INTER_LINEAR
    # resizing the identity along x maps unit vector e_i to column i of R
    return np.ascontiguousarray(cv2.resize(np.eye(side, dtype=np.float32), (size, side), interpolation=interp).T)


def preprocess_fn(frame_size, input_size: int, mean, std):
    """jnp version of data.preprocess_image for fixed (H, W): uint8 (B,H,W,3) + (H,W,3) -> (B,S,S,3)."""
    h, w = frame_size
    side = max(h, w)
    r = resize_matrix(side, input_size)
    top, left = (side - h) // 2, (side - w) // 2
    # padding with 0 adds nothing to a weighted sum: fold it into the resize matrices
    ry, rx = jnp.asarray(r[:, top:top + h]), jnp.asarray(r[:, left:left + w])
    mean, std = jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32)

    def fn(images, background):
        nobg = jnp.clip(images.astype(jnp.int32) - background.astype(jnp.int32) + 127, 0, 255)
        x = jnp.einsum("sh,bhwc,tw->bstc", ry, nobg.astype(jnp.float32), rx, precision="highest")
        return (x * np.float32(1 / 255) - mean) / std

    return fn


def forces_fn(pred: inference.Predictor):
    """f(images uint8 (B,H,W,3) RGB, background uint8 (H,W,3) RGB) -> forces float32 (B,3), weights closed over."""
    pre = preprocess_fn(pred.frame_size, pred.input_size, pred.stats.mean, pred.stats.std)
    model, variables = pred.model, jax.tree.map(jnp.asarray, pred.trained.variables)

    def fn(images, background):
        return model.apply(variables, pre(images, background), train=False)["force"]

    return fn


def export(pred: inference.Predictor, batch: int = 1, platforms=None) -> jax.export.Exported:
    """The jax.export.Exported of `forces_fn`; batch 0 = symbolic batch size; platforms among PLATFORMS."""
    if int(batch) < 0:
        raise ValueError(f"batch must be >= 1, or 0 for a symbolic batch size; got {batch}")
    if platforms:
        platforms = parse_platforms(platforms if isinstance(platforms, str) else ",".join(platforms))
    h, w = pred.frame_size
    b = jax.export.symbolic_shape("b")[0] if batch == 0 else int(batch)
    args = (jax.ShapeDtypeStruct((b, h, w, 3), jnp.uint8), jax.ShapeDtypeStruct((h, w, 3), jnp.uint8))
    kw = {"platforms": tuple(platforms)} if platforms else {}
    return jax.export.export(jax.jit(forces_fn(pred)), **kw)(*args)


def parse_platforms(text: str) -> tuple[str, ...]:
    """'cpu,cuda' -> ('cpu', 'cuda'); anything outside PLATFORMS is refused (jax would export it and the
    function would fail when called). An argparse type."""
    names = [t.strip().lower() for t in str(text).split(",")]
    bad = [n for n in names if n not in PLATFORMS]
    if bad:
        hint = " ('gpu' is cuda for NVIDIA, rocm for AMD)" if "gpu" in bad else ""
        raise cli.BadValue(f"expected a comma-separated list of {', '.join(PLATFORMS)}, got {text!r}{hint}")
    return tuple(dict.fromkeys(names))  # a platform named twice is exported once


def sidecar_path(path) -> Path:
    return Path(f"{path}.json")


def save(pred: inference.Predictor, path, batch: int = 1, platforms=None) -> Path:
    """Write the serialized function to `path` and its description (with the file's sha256) to `path`.json;
    returns `path`. A kill or a full disk never leaves half a file; between the two files it leaves an export
    that its old sidecar refuses. Temp files of an earlier export killed mid-write are removed."""
    exp = export(pred, batch, platforms)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for target in (path, sidecar_path(path)):
        remove_stale_temps(target)
    raw = exp.serialize()
    atomic_write_bytes(path, raw)
    info = {
        "format": FORMAT,
        "inputs": {"images": f"uint8 ({'B' if batch == 0 else batch}, H, W, 3) {inference.CHANNELS}",
                   "background": f"uint8 (H, W, 3) {inference.CHANNELS}, the no-contact frame"},
        "output": "float32 (B, 3): Fx, Fy, Fz in newtons",
        "batch": None if batch == 0 else int(batch),
        "platforms": list(exp.platforms),
        "checkpoint": pred.describe() | {"path": pred.trained.path},
        "frame_size": list(pred.frame_size),
        "channels": inference.CHANNELS,
        "force_min": pred.force_min.tolist(),
        "force_max": pred.force_max.tolist(),
        "jax_version": jax.__version__,
        "sha256": sha256_bytes(raw),
    }
    atomic_write_json(sidecar_path(path), info, indent=2)
    return path


class ExportedPredictor:
    """A loaded export: call(images, background) -> forces (B, 3) numpy; last_out_of_range and last_nonfinite
    like Predictor. A missing, truncated or foreign file (or sidecar) is an error naming it."""

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: no such export file (python -m ffjax.export --out FILE ...)")
        side = sidecar_path(self.path)
        self.info = read_json(side) or {}
        raw = self.path.read_bytes()
        if self.info.get("sha256") and sha256_bytes(raw) != self.info["sha256"]:
            raise CheckpointError(f"{self.path} is corrupt, truncated or from another export: its sha256 differs "
                                  f"from the one in {side.name}; export it again")
        ck = self.info.get("checkpoint")
        how = (f"export it again: python -m ffjax.export --checkpoint "
               f"{ck['path'] if isinstance(ck, dict) and ck.get('path') else 'RUN'} --out {self.path} --force")
        if not self.info:
            warnings.warn(f"{self.path} has no {side.name} beside it: the file is not verified (an edit would change "
                          f"the forces unnoticed) and frame sizes are not checked. To make it verified again, {how}",
                          UnverifiedWarning, stacklevel=2)
        elif not self.info.get("sha256"):
            warn_unverified(side, ["sha256"], f"{self.path.name} is", how)
        try:
            self.exported = jax.export.deserialize(bytearray(raw))
        except Exception as e:  # noqa: BLE001 - flatbuffers/struct errors of a damaged file name neither it nor why
            raise CheckpointError(f"{self.path} is not a readable jax export (truncated, corrupt or another file: "
                                  f"{type(e).__name__}); export it again") from e
        self.last_out_of_range = self.last_nonfinite = np.zeros((0,), bool)

    def __call__(self, images, background) -> np.ndarray:
        images, background = np.asarray(images), np.asarray(background)
        if images.ndim == 3:
            images = images[None]
        for what, x, ndim in (("images", images, 4), ("background", background, 3)):
            if x.ndim != ndim or x.shape[-1] != 3:
                hint = " (RGBA/BGRA: drop the alpha channel)" if x.ndim == ndim and x.shape[-1] == 4 else ""
                raise ValueError(f"{what} must be {'(B, H, W, 3)' if ndim == 4 else '(H, W, 3)'} RGB for {self.path}, "
                                 f"got shape {x.shape}{hint}")
        if not len(images):  # no frames, no forces (as Predictor.predict)
            self.last_out_of_range = self.last_nonfinite = np.zeros((0,), bool)
            return np.zeros((0, 3), np.float32)
        batch = self.exported.in_avals[0].shape[0]
        if isinstance(batch, int) and images.shape[0] != batch:
            raise ValueError(f"{self.path} takes batches of exactly {batch} frame(s), got {images.shape[0]}: call it "
                             f"per {batch} frame(s), or export with --batch 0 for any batch size")
        fs = self.info.get("frame_size")
        if fs and (tuple(images.shape[1:3]) != tuple(fs) or tuple(background.shape[:2]) != tuple(fs)):
            raise ValueError(f"frames {images.shape[1:3]} / background {background.shape[:2]} must be "
                             f"{tuple(fs)} (HxW) for this export")
        if images.dtype != np.uint8 or background.dtype != np.uint8:
            raise TypeError("images and background must be uint8 RGB")
        forces = np.asarray(self.exported.call(images, background), np.float32)
        self.last_nonfinite = ~np.isfinite(forces).all(axis=1)
        self.last_out_of_range = self.last_nonfinite.copy()
        if "force_min" in self.info:
            lo, hi = np.minimum(self.info["force_min"], 0), np.maximum(self.info["force_max"], 0)
            tol = 0.05 * (hi - lo)
            self.last_out_of_range |= np.any((forces < lo - tol) | (forces > hi + tol), axis=1)
        if self.last_nonfinite.any():
            warnings.warn(f"non-finite (NaN/inf) forces from {self.path}: the exported weights or the input are "
                          "corrupt; do not act on them (see last_nonfinite)", inference.NonFiniteWarning,
                          stacklevel=2)
        return forces


def load(path) -> ExportedPredictor:
    return ExportedPredictor(path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m ffjax.export", description=cli.description(__doc__),
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(__doc__.splitlines()[1:]))
    p.add_argument("--checkpoint", required=True, help="training run, calibrated or converted folder")
    p.add_argument("--out", required=True, help="output file (a .json sidecar is written beside it)")
    p.add_argument("--batch", type=cli.integer(0, "0: a symbolic batch size, any batch"), default=1,
                   help="fixed batch size (0: symbolic); default 1")
    p.add_argument("--which", default="best", choices=("best", "latest"), help=cli.WHICH_HELP)
    p.add_argument("--platforms", type=parse_platforms, default=None,
                   help=f"comma-separated lowering targets among {', '.join(PLATFORMS)}, e.g. cpu,cuda (default: "
                   "this machine's)")
    p.add_argument("--frame-size", type=cli.frame_size, default=None,
                   help="HxW of the sensor frames, if the checkpoint lacks it")
    p.add_argument("--force", action="store_true", help="replace an existing export (and its sidecar)")
    a = p.parse_args(argv)
    for target in (a.out, sidecar_path(a.out)):  # before loading and compiling
        check_output(target, reads=[a.checkpoint], force=a.force)
    cli.check_out(p, Path(a.out).absolute().parent)
    with cli.sigterm_as_interrupt():  # a stopped export removes its temp file, as on Ctrl-C
        pred = inference.load(a.checkpoint, a.which, frame_size=a.frame_size)
        path = save(pred, a.out, a.batch, a.platforms)
    print(f"exported {a.checkpoint} -> {path} (+ {sidecar_path(path).name}); frames {pred.frame_size[0]}x"
          f"{pred.frame_size[1]} RGB uint8, batch {a.batch or 'symbolic'}")
    return 0


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
