"""The run state as one flat buffer per dtype, for the resume checkpoints.

orbax writes every tensor as its own entry, each at a cost of CPU: the quick run state's ~200 tensors cost
CPU at every save, on the cores the train step shares (issue 14). Packed, the same state is three buffers
(float32, int32, uint32), at a fraction of that (measured: docs/benchmarks.md). The layout (each tensor's
path, dtype and shape, in tree order) is saved beside the buffers, so the parameters can be read back without
the optimizer's tree.
The best checkpoint, the one users load, stays a plain tensor tree.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def packable(tree) -> bool:
    """Whether every leaf is a plain numeric array (typed PRNG keys are not)."""
    return all(isinstance(x.dtype, np.dtype) for x in jax.tree.leaves(tree))


def layout(tree) -> list[list]:
    """[[path, dtype, shape], ...] in tree order; path is the key list for dict-only paths (params,
    batch_stats), else jax's key string."""
    out = []
    for path, x in jax.tree_util.tree_flatten_with_path(tree)[0]:
        keys = [getattr(k, "key", None) for k in path]
        name = [str(k) for k in keys] if all(isinstance(k, str) for k in keys) else jax.tree_util.keystr(path)
        out.append([name, str(np.dtype(x.dtype)), [int(d) for d in x.shape]])
    return out


@jax.jit
def pack(tree) -> dict:
    """{dtype name: 1-D buffer} holding every leaf raveled, in tree order (one program, on the device)."""
    groups: dict = {}
    for x in jax.tree.leaves(tree):
        groups.setdefault(str(np.dtype(x.dtype)), []).append(jnp.ravel(x))
    return {d: jnp.concatenate(v) if len(v) > 1 else v[0] for d, v in groups.items()}


def buffer_sizes(saved_layout: list) -> dict:
    """{dtype name: total elements} of a layout: the buffers' shapes."""
    sizes: dict = {}
    for _, dtype, shape in saved_layout:
        sizes[dtype] = sizes.get(dtype, 0) + int(np.prod(shape, dtype=np.int64))
    return sizes


def unpack_leaves(buffers: dict, saved_layout: list) -> list:
    """The leaves back from `pack`'s buffers, in tree order; ValueError when the sizes do not add up."""
    sizes = buffer_sizes(saved_layout)
    for d, n in sizes.items():
        if d not in buffers or int(np.shape(buffers[d])[0]) != n:
            got = None if d not in buffers else np.shape(buffers[d])
            raise ValueError(f"packed {d} buffer holds {got}, the layout needs ({n},)")
    offset = dict.fromkeys(sizes, 0)
    leaves = []
    for _, dtype, shape in saved_layout:
        n = int(np.prod(shape, dtype=np.int64))
        leaves.append(buffers[dtype][offset[dtype]: offset[dtype] + n].reshape(shape))
        offset[dtype] += n
    return leaves


def unpack(buffers: dict, saved_layout: list, template):
    """`template`'s tree from the buffers; ValueError naming the first tensor whose saved path or shape is not
    the template's (a checkpoint of another model or optimizer)."""
    ours = layout(template)
    if len(ours) != len(saved_layout):
        raise ValueError(f"structure mismatch: the checkpoint holds {len(saved_layout)} tensors, this model "
                         f"and optimizer {len(ours)}")
    for (p, d, s), (q, e, t) in zip(saved_layout, ours):
        if (p, d, list(s)) != (q, e, t):
            raise ValueError(f"shape mismatch: checkpoint tensor {p} {d}{list(s)} vs this model's {q} {e}{t}")
    return jax.tree.unflatten(jax.tree.structure(template), unpack_leaves(buffers, saved_layout))


def variables_from(buffers: dict, saved_layout: list) -> dict:
    """{"params": .., "batch_stats": ..} nested dicts from the buffers, without a template."""
    out: dict = {"params": {}, "batch_stats": {}}
    for (path, _, _), leaf in zip(saved_layout, unpack_leaves(buffers, saved_layout)):
        if isinstance(path, list) and path and path[0] in out:
            node = out[path[0]]
            for k in path[1:-1]:
                node = node.setdefault(k, {})
            node[path[-1]] = leaf
    return out
