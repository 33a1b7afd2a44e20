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
        "regressor": {"widths": (32, 16, 16, 8), "normalize_output": True, "out_scale": None, "out_shift": None,
                      "feature_norm": True},
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
        # validate (and pick the best checkpoint) every this many epochs; the last epoch always validates
        "val_every": 1,
        "grad_clip": 0.0,
        # a NaN/inf loss or gradient: "stop" (raise, naming the step and batch) or "skip" (drop that update)
        "nonfinite": "stop",
        # force term of the loss: "newton" (L1 in N, the release) or "normalized" (each axis / its range)
        "force_loss": "normalized",
        # forward/backward precision of the train step: "float32" or "bfloat16" (float32 master weights,
        # float32 losses, optimizer and BatchNorm statistics; evaluation stays float32)
        "compute_dtype": "float32",
    },
    "pretrain": {
        "steps": 4, "batch_size": 8, "lr": 5e-4, "corpus_size": 32, "out_dim": 64,
        # DINO self-distillation (ffjax.train.pretrain); tiny: a few steps for tests
        "warmup_steps": 1, "min_lr_ratio": 0.05, "weight_decay": 0.04, "grad_clip": 3.0,
        "head_hidden": 64, "head_bottleneck": 32, "freeze_last_steps": 1, "init_layerscale": 0.1, "head_bn": True,
        "local_crops": 2, "local_size": 16, "global_scale": (0.4, 1.0), "local_scale": (0.1, 0.4),
        "student_temp": 0.1, "teacher_temp": 0.05, "teacher_temp_start": 0.04, "teacher_temp_warmup": 2,
        "momentum": 0.996, "center_momentum": 0.9,
        "flip": 0.5, "color_jitter": 0.4, "blur": 0.5, "noise": 0.1, "corpus_sim_fraction": 0.5,
    },
    "calibrate": {"steps": 5, "lr": 1e-4, "batch_size": 8, "holdout": 0.2},
}
