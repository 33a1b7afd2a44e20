"""`paper`: ViT-B/14 at 224x224 with the release's heads and hyper-parameters; for a GPU and real data."""

CONFIG = {
    "seed": 0,
    "data": {
        "render_size": (240, 320),
        "input_size": 224,
        "train_per_indenter": 20000,
        "val_per_indenter": 1000,
        "unseen_per_object": 500,
        "sensor_test_per_indenter": 200,
        "calib_samples": 100,
        "fz_max": 15.0,
        "shear_max": 2.0,
        "shard_size": 1024,
        "depth_eps": 0.05,
    },
    "model": {
        "vit": {"dim": 768, "depth": 12, "heads": 12, "patch": 14, "mlp_ratio": 4.0, "layerscale": 1e-5,
                "pos_grid": 37},
        "resnet": {"widths": (64, 128, 256, 512), "blocks": (2, 2, 2, 2), "stem": "imagenet"},
        "regressor": {"widths": (512, 256, 128, 64), "normalize_output": True, "out_scale": None, "out_shift": None,
                      "feature_norm": False},
        "decoder": {"kind": "paper", "channels": (512, 256, 256, 128)},
    },
    "train": {
        "batch_size": 128,
        "epochs": 100,
        "lr_backbone": 1e-5,
        "lr_heads": 5e-5,
        "schedule": "constant",
        "warmup_steps": 1000,
        "ckpt_every": 2000,
        # validate (and pick the best checkpoint) every this many epochs; the last epoch always validates
        "val_every": 1,
        "grad_clip": 0.0,
        # a NaN/inf loss or gradient: "stop" (raise, naming the step and batch) or "skip" (drop that update)
        "nonfinite": "stop",
        # force term of the loss: "newton" (L1 in N, the release) or "normalized" (each axis / its range)
        "force_loss": "newton",
        # forward/backward precision of the train step: "float32" or "bfloat16" (float32 master weights,
        # float32 losses, optimizer and BatchNorm statistics; evaluation stays float32)
        "compute_dtype": "float32",
    },
    "pretrain": {
        "steps": 0, "batch_size": 128, "lr": 5e-4, "corpus_size": 0, "out_dim": 65536,
        # DINO self-distillation (ffjax.train.pretrain); paper scale loads real DINOv2 weights instead
        "warmup_steps": 10, "min_lr_ratio": 0.05, "weight_decay": 0.04, "grad_clip": 3.0,
        "head_hidden": 2048, "head_bottleneck": 256, "freeze_last_steps": 10, "init_layerscale": 0.1, "head_bn": True,
        "local_crops": 8, "local_size": 98, "global_scale": (0.32, 1.0), "local_scale": (0.05, 0.32),
        "student_temp": 0.1, "teacher_temp": 0.07, "teacher_temp_start": 0.04, "teacher_temp_warmup": 30,
        "momentum": 0.996, "center_momentum": 0.9,
        "flip": 0.5, "color_jitter": 0.4, "blur": 0.5, "noise": 0.1, "corpus_sim_fraction": 0.5,
    },
    "calibrate": {"steps": 300, "lr": 1e-4, "batch_size": 32, "holdout": 0.2},
}
