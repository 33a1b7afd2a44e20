"""`gpu`: the converged regime on one GPU: quick's data twice over, quick's old (larger) ViT, batch 256.

Sized for a short whole ablation on one H100-class GPU: at these sizes a step there costs about the same at
batch 256 as at 64, so ~6,000 steps per method see ~1.5 M samples (~130 epochs of the 12,000 training
presses; the earlier GPU runs' 150 epochs at batch 64 saw 0.9 M). Not yet run whole on a GPU by this
project: the tables in README come from quick and full. The step and training-loop times measured on a GPU
are in docs/benchmarks.md.
"""

from configs.checks import derive
from configs.quick import CONFIG as _QUICK

CONFIG = derive(_QUICK, {
    "data": {"train_per_indenter": 1200, "val_per_indenter": 100, "unseen_per_object": 200,
             "sensor_test_per_indenter": 60},
    "model": {"vit": {"dim": 128, "depth": 4, "heads": 4}, "resnet": {"widths": (32, 64, 128, 256)},
              "decoder": {"channels": (64, 32, 32, 16)}},
    "train": {"batch_size": 256, "epochs": 128, "warmup_steps": 200, "ckpt_every": 1000},
    "pretrain": {"steps": 1000, "batch_size": 128, "corpus_size": 20000},
})
