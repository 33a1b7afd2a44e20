"""`quick`: the README's main command; every table end to end on a 2-core CPU in < 30 min, trained models.

Scale note: 48x64 renders padded to 64x64, a ViT of dim 64 / depth 2 / patch 8, a ResNet with the
torchvision stem (stride 4), 6,000 training presses, 15 epochs (1,395 steps). Sized from measurements on
the 2-core CPU (jitted step, batch 64): ViT 128/4 + decoder 750 ms, ViT 64/2 + the (32,16,16,8) decoder
170 ms; ResNet with the stride-1 stem 3.0 s, with the torchvision stem 240 ms. The same budget rule for
every method: the same data, batch and number of steps; each backbone the smallest of its family whose
step costs ~200 ms here. It shows the paper's effects at toy scale; it does not reproduce its absolute
numbers.
"""

CONFIG = {
    "seed": 0,
    "data": {
        "render_size": (48, 64),  # (H, W) of the simulated frame; 240x320 is native
        "input_size": 64,  # square model input after pad + resize
        "train_per_indenter": 600,
        "val_per_indenter": 60,
        "unseen_per_object": 100,
        "sensor_test_per_indenter": 30,
        "calib_samples": 100,
        "fz_max": 15.0,
        "shear_max": 2.0,
        "shard_size": 512,
        "depth_eps": 0.05,  # mm; the release's eps is 5 in its depth units
    },
    "model": {
        "vit": {"dim": 64, "depth": 2, "heads": 4, "patch": 8, "mlp_ratio": 4.0, "layerscale": 1e-5,
                "pos_grid": None},
        "resnet": {"widths": (16, 32, 64, 128), "blocks": (2, 2, 2, 2), "stem": "imagenet"},
        "regressor": {"widths": (256, 128, 64, 32), "normalize_output": True, "out_scale": None, "out_shift": None,
                      "feature_norm": True},
        "decoder": {"kind": "tokens", "channels": (32, 16, 16, 8)},
    },
    "train": {
        "batch_size": 64,
        "epochs": 15,
        # CPU scale trains ~1.4k steps, not the paper's ~150k: higher rates with warmup + cosine decay
        # (at 1e-4 / 5e-4 constant, 3 epochs reached val Fz MAE 2.24 N; at these, 2.05 N).
        "lr_backbone": 5e-4,
        "lr_heads": 1e-3,
        "schedule": "warmup_cosine",  # constant | warmup_cosine
        "warmup_steps": 50,
        "ckpt_every": 200,
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
        "steps": 180, "batch_size": 32, "lr": 5e-4, "corpus_size": 6000, "out_dim": 1024,
        # DINO self-distillation (ffjax.train.pretrain); sized for ~2-3 min per backbone on 2 cores
        "warmup_steps": 20, "min_lr_ratio": 0.05, "weight_decay": 0.04, "grad_clip": 3.0,
        "head_hidden": 512, "head_bottleneck": 128, "freeze_last_steps": 10, "init_layerscale": 0.1, "head_bn": True,
        "local_crops": 4, "local_size": 32, "global_scale": (0.4, 1.0), "local_scale": (0.1, 0.4),
        "student_temp": 0.1, "teacher_temp": 0.05, "teacher_temp_start": 0.04, "teacher_temp_warmup": 60,
        "momentum": 0.996, "center_momentum": 0.9,
        "flip": 0.5, "color_jitter": 0.4, "blur": 0.5, "noise": 0.1, "corpus_sim_fraction": 0.5,
    },
    "calibrate": {"steps": 200, "lr": 1e-4, "batch_size": 32, "holdout": 0.2},
}
