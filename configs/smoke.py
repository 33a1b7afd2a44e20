"""`smoke`: seconds; tiny models and images, for tests and notebooks. Numbers mean nothing."""

CONFIG = {
    "seed": 0,
    "data": {
        "render_size": (24, 32),
        "input_size": 32,
        "train_per_indenter": 12,
        "val_per_indenter": 4,
        "unseen_per_object": 4,
        "sensor_test_per_indenter": 2,
        "calib_samples": 20,
        "fz_max": 15.0,
        "shear_max": 2.0,
        "shard_size": 64,
        "depth_eps": 0.05,
    },
    "model": {
        "vit": {"dim": 32, "depth": 2, "heads": 2, "patch": 8, "mlp_ratio": 2.0, "layerscale": 1e-5,
                "pos_grid": None},
        "resnet": {"widths": (8, 16, 16, 32), "blocks": (1, 1, 1, 1), "stem": "small"},
        "regressor": {"widths": (32, 16, 16, 8), "normalize_output": True, "out_scale": None, "out_shift": None},
        "decoder": {"kind": "tokens", "channels": (16, 8, 8, 8)},
    },
    "train": {
        "batch_size": 8,
        "epochs": 1,
        "lr_backbone": 1e-4,
        "lr_heads": 5e-4,
        "schedule": "constant",
        "warmup_steps": 2,
        "ckpt_every": 5,
        "grad_clip": 0.0,
    },
    "pretrain": {"steps": 4, "batch_size": 8, "lr": 5e-4, "corpus_size": 32, "out_dim": 64},
    "calibrate": {"steps": 5, "lr": 1e-4, "batch_size": 8, "holdout": 0.2},
}
