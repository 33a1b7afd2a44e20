"""`gpu`: the converged regime on one GPU: quick's data twice over, quick's old (larger) ViT, batch 256.

Sized for <= 10 min of the whole ablation on one H100-class GPU, from the issue's measurements there (jax
0.11 + CUDA): the training loop ran at ~18 ms per step for the quick ViT at batch 64, and at these sizes a
step costs about the same at batch 256, so ~6,000 steps per method see ~1.5 M samples (~130 epochs of the
12,000 training presses; the earlier GPU runs' 150 epochs at batch 64 saw 0.9 M). Not yet run on a GPU by
this project: the tables in README come from quick and full. Measured since on one H200 (jax 0.11.2,
`experiments.bench --quick --device gpu --only loop`): the quick ViT's step 2.1-2.5 ms at batch 64, the training
loop 5.2 ms per step validating every 5th epoch and 10.2 ms validating every epoch (15bd518); 2.5-3.2, 8.3 and
8.7 ms in a second run (d6bb2a3).
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
