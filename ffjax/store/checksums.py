"""Per-tensor checksums of a pytree, computed on the device: saved with every checkpoint and compared after
restoring, so a flipped byte in a data file is an error naming the tensor instead of a model that predicts NaN.
And the one warning for a file that carries no digest at all (`warn_unverified`)."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp

from ffjax.errors import CheckpointError

_UNSIGNED = {1: jnp.uint8, 2: jnp.uint16, 4: jnp.uint32}


@jax.jit
def _leaf_sums(leaves):
    def one(x):
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            x = jax.random.key_data(x)
        if x.dtype == jnp.bool_:
            x = x.astype(jnp.uint8)
        u = jax.lax.bitcast_convert_type(x, _UNSIGNED[x.dtype.itemsize]).astype(jnp.uint32).ravel()
        pos = jnp.arange(1, u.size + 1, dtype=jnp.uint32)
        # a plain sum misses swapped values, the position-weighted one catches them (Fletcher-style, mod 2^32)
        return jnp.stack([u.sum(dtype=jnp.uint32), (u * pos).sum(dtype=jnp.uint32)])

    return [one(x) for x in leaves]


def tree_checksums(tree) -> dict[str, str]:
    """Per-tensor checksums of a pytree ({"['params']['dense']['kernel']": "0123abcd89ef4567", ...}), computed
    on the device (one small transfer): saved with every checkpoint and compared after restoring, so a
    flipped byte in a data file is an error naming the tensor instead of a model that predicts NaN."""
    paths, leaves = zip(*jax.tree_util.tree_flatten_with_path(tree)[0]) if jax.tree.leaves(tree) else ((), ())
    sums = jax.device_get(_leaf_sums(list(leaves)))
    return {jax.tree_util.keystr(p): f"{int(a):08x}{int(b):08x}" for p, (a, b) in zip(paths, sums)}


def verify_checksums(tree, saved: dict | None, path) -> None:
    """Raise CheckpointError naming `path` and the first tensor whose data differ from what was saved
    (checkpoints written before checksums existed carry none and pass)."""
    if not saved:
        return
    now = tree_checksums(tree)
    bad = [k for k in saved if now.get(k) != saved[k]]
    if bad or set(now) != set(saved):
        what = (f"tensor {bad[0]} differs" + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else "")) if bad \
            else "its tensor list differs"
        raise CheckpointError(f"{path} is corrupt: {what} from the checksums saved with it (a disk or copy error "
                              "changed the files)")


class UnverifiedWarning(UserWarning):
    """A model file carries no digest (written before ffjax recorded one, or edited and the digest removed): it
    loads, but an edit to it would change the forces unnoticed."""


def warn_unverified(path, missing: list[str], what: str, how: str) -> None:
    """Warn that `path` records none of the digests `missing`, so `what` ("the weights are") is not verified, and
    `how` makes it verified again. Once per load: the loaders call it where the file is read."""
    text = (f"{path} records no {' and no '.join(missing)} (written before ffjax recorded digests, or a digest was "
            f"deleted): {what} not verified, so an edit would go unnoticed. To make it verified again, {how}")
    # a path's undecodable bytes shown escaped: the message is text (a log, a test runner's report must encode it)
    warnings.warn(text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace"), UnverifiedWarning,
                  stacklevel=3)
