"""Training: a pure jitted step over a pytree state, the epoch loop, checkpoints and run folders.

    state = train.init_state(cfg, spec, key, input_size)          # params, batch_stats, opt_state, key
    state, m = train.train_step(state, batch)                      # jitted once; m: loss, force_l1, ...
    summary = train.train(cfg, "dino_rd", "data/quick", "runs/x")  # or python -m ffjax.train

A run folder is read back with `ffjax.store.load("runs/x")` (any process, any variant): ffjax.store is the one
reader of trained models in every form.

The objective (the loss terms, each declared once) lives in `ffjax.train.objective`.

Pretraining (self-supervised backbones) lives in `ffjax.train.pretrain`.
"""

from ffjax.train.loop import open_sources, train
from ffjax.train.nonfinite import NonFiniteLossError
from ffjax.train.state import (
    Labeler,
    TrainState,
    abstract_state,
    init_state,
    learning_rate,
    make_optimizer,
    replace_backbone,
)
from ffjax.train.step import TRACE_COUNT, eval_step, make_mesh, replicate, shard_batch, train_step
from ffjax.train.validation import validate

__all__ = [
    "TRACE_COUNT",
    "Labeler",
    "NonFiniteLossError",
    "TrainState",
    "abstract_state",
    "eval_step",
    "init_state",
    "learning_rate",
    "make_mesh",
    "make_optimizer",
    "open_sources",
    "replace_backbone",
    "replicate",
    "shard_batch",
    "train",
    "train_step",
    "validate",
]
