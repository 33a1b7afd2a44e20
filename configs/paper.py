"""`paper`: ViT-B/14 at 224x224 with the release's heads and hyper-parameters; for a GPU and real data."""

from configs.base import CONFIG as _BASE
from configs.checks import derive

CONFIG = derive(_BASE, {
    "data": {"render_size": (240, 320), "input_size": 224, "train_per_indenter": 20000, "val_per_indenter": 1000,
             "unseen_per_object": 500, "sensor_test_per_indenter": 200, "shard_size": 1024},
    "model": {
        "vit": {"dim": 768, "depth": 12, "heads": 12, "patch": 14, "pos_grid": 37},
        "resnet": {"widths": (64, 128, 256, 512)},
        "regressor": {"widths": (512, 256, 128, 64), "feature_norm": False},
        "decoder": {"kind": "paper", "channels": (512, 256, 256, 128)},
    },
    "train": {"batch_size": 128, "epochs": 100, "lr_backbone": 1e-5, "lr_heads": 5e-5, "schedule": "constant",
              "warmup_steps": 1000, "ckpt_every": 2000, "force_loss": "newton"},
    # DINO self-distillation is not run at paper scale (steps 0): it loads real DINOv2 weights instead
    "pretrain": {"steps": 0, "batch_size": 128, "corpus_size": 0, "out_dim": 65536, "warmup_steps": 10,
                 "head_hidden": 2048, "head_bottleneck": 256, "local_crops": 8, "local_size": 98,
                 "global_scale": (0.32, 1.0), "local_scale": (0.05, 0.32), "teacher_temp": 0.07,
                 "teacher_temp_warmup": 30},
    "calibrate": {"steps": 300},
})
