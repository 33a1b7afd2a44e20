"""`smoke`: tiny models and images, for the tests and notebooks; its numbers check the plumbing and carry no verdict."""

from configs.base import CONFIG as _BASE
from configs.checks import derive

CONFIG = derive(_BASE, {
    "data": {"render_size": (24, 32), "input_size": 32, "train_per_indenter": 12, "val_per_indenter": 4,
             "unseen_per_object": 4, "sensor_test_per_indenter": 2, "calib_samples": 20, "shard_size": 64,
             "path_steps": 2},
    "model": {
        "vit": {"dim": 32, "heads": 2, "mlp_ratio": 2.0},
        "resnet": {"widths": (8, 16, 16, 32), "blocks": (1, 1, 1, 1), "stem": "small"},
        "regressor": {"widths": (32, 16, 16, 8)},
        "decoder": {"channels": (16, 8, 8, 8)},
    },
    "train": {"batch_size": 8, "epochs": 1, "lr_backbone": 1e-4, "lr_heads": 5e-4, "schedule": "constant",
              "warmup_steps": 2, "ckpt_every": 5},
    # DINO pretraining: tiny, a few steps for tests
    "pretrain": {"steps": 4, "batch_size": 8, "corpus_size": 32, "out_dim": 64, "warmup_steps": 1, "head_hidden": 64,
                 "head_bottleneck": 32, "freeze_last_steps": 1, "local_crops": 2, "local_size": 16,
                 "teacher_temp_warmup": 2},
    "calibrate": {"steps": 5, "batch_size": 8},
    "report": {"verdicts": False},  # its numbers check the plumbing: they judge nothing
})
