"""Every config key once: its default, the check its values must pass, and (in a comment) what it does.

The defaults are the `quick` preset (the README's main command); every other preset is its differences from
this (configs/smoke.py, paper.py) or from another preset (full.py, gpu.py). `configs.validate` runs the checks
below; keys checked together (input_size vs. patch, ...) are in configs/__init__.py `_cross_checks`.
A config saved before a key existed (model.json of an earlier run) is read through `configs.upgrade`, which
fills the key with `before=`: the value the code used then (the default where none is given). `late=True` marks
the keys added after runs and datasets were saved: caches hash configs without them while they hold that value.
"""

from configs.checks import NN, NN_INT, POS, POS_INT, PROB, SCALE, Key, because, boolean, choice, defaults, num, seq
from ffjax.sim import INDENTERS, mechanics, seeds
from ffjax.sim.sensors import PRESETS, SENSOR_NAMES

_FORCE3 = seq(num(), length=3, optional=True)
# px, a side of a rendered frame or of the model input: twice the longest native frame side of the sensors (GelSight
# Mini 240x320, DIGIT 320x240); finer shows nothing their cameras resolve, and memory grows with the area
MAX_PX = 2 * max(max(s.native_size) for s in PRESETS.values())
_PX = because(num(1, MAX_PX, integer=True), f"{MAX_PX} px is twice the longest native frame side of the sensors "
                                            "(finer shows nothing their cameras resolve)")


def _presses(shapes: int):
    """Presses per shape of a simulated split of `shapes` shapes: at least one (an empty split fails where it is
    read), few enough for the split's block of render seeds (ffjax.sim.seeds)."""
    return because(num(1, seeds.BLOCK // shapes, integer=True),
                   f"a simulated split holds 1 to {seeds.BLOCK} presses (its block of render seeds)")


_PER_INDENTER, _PER_OBJECT = _presses(len(INDENTERS)), _presses(1)


SPEC = {
    # root of every random stream: data, init, shuffling, augmentation
    "seed": Key(0, because(num(0, seeds.MAX_SEED, integer=True),
                           f"split k of config seed s renders with the seeds from (s * {seeds.MAX_SPLITS} + k) * "
                           f"{seeds.BLOCK} on, which must fit in int64 (ffjax.sim.seeds)")),
    "seeds": Key(1, POS_INT),  # how many seeds (seed, seed + 1, ...) the experiments run unless told otherwise
    "data": {
        "render_size": Key((48, 64), seq(_PX, length=2)),  # (H, W) of the simulated frame; 240x320 is native
        "input_size": Key(64, _PX),  # square model input after pad + resize
        "train_per_indenter": Key(600, _PER_INDENTER),  # training presses per indenter (10 indenters)
        "val_per_indenter": Key(60, _PER_INDENTER),  # validation presses per indenter
        "unseen_per_object": Key(100, _PER_OBJECT),  # Table I: presses per unseen object
        "sensor_test_per_indenter": Key(30, _PER_INDENTER),  # Table II: presses per indenter on every sensor
        "calib_samples": Key(100, _PER_OBJECT),  # Table III: calibration presses per sensor (the paper's ~100)
        # sensor of the train, val and unseen splits
        "train_sensor": Key("mini-1-gel1", choice(*SENSOR_NAMES), late=True),
        "fz_min": Key(0.05, NN, late=True),  # N; Fz is stratified over [fz_min, fz_max] per shape
        "fz_max": Key(15.0, POS),  # N
        # how a press loads the gel: "oblique", the paper's press along the tilted tool axis (the shear comes from
        # the path); "shear": pressed to Fz, then Fz * tan(tilt) + noise applied sideways in stick (before issue 32)
        "loading": Key("oblique", choice("oblique", "shear"), before="shear"),
        # oblique: the press's path in steps and how a step's stiffness stands for it (mechanics.oblique_batch): the
        # simulator's own defaults, chosen by measurement there (mechanics.PATH_STEPS)
        "path_steps": Key(mechanics.PATH_STEPS, POS_INT),
        "path_quadrature": Key(mechanics.PATH_QUADRATURE, choice(*mechanics.QUADRATURES), before="midpoint"),
        # roll/pitch of a press uniform in +-tilt_max_deg; 15: the release's Fx, Fy of +-2 N at Fz 15 N
        # (docs/simulator.md)
        "tilt_max_deg": Key(15.0, num(0, 90, hi_open=True), before=7.0),
        "shear_noise": Key(0.06, NN, late=True),  # shear: std of the shear beyond Fz * tan(tilt), a fraction of Fz
        "shear_max": Key(2.0, NN),  # N; shear: |Fx|, |Fy| are redrawn above it (the simulator caps at mu * Fz)
        # oblique loading: this share of each shape's presses is pushed sideways after contact instead (Fx, Fy
        # uniform in +-shear_max, stick or, where Coulomb caps it, partial slip), its shear drawn apart from the lean
        "sideways_share": Key(0.0, PROB, late=True),
        "ft_noise": Key(0.005, NN, before=0.0),  # N per axis on the labels: the release's F/T sensor at rest
        # share of the fine fixed pattern that is pigment on the gel (moves with it); not measurable at rest
        "pattern_moving": Key(0.5, PROB, before=1.0),
        "shard_size": Key(512, POS_INT),  # presses per .npz shard on disk
        # mm; widens the depth normalization range (train min - eps, max + eps); the release's is 5 depth units
        "depth_eps": Key(0.05, NN, before=0.0),
    },
    "model": {
        # one section per backbone kind (ffjax.models.BACKBONES), built by that kind's from_config
        "vit": {
            "dim": Key(64, POS_INT),  # token width
            "depth": Key(2, POS_INT),  # transformer blocks
            "heads": Key(4, POS_INT),  # attention heads (dim must divide by it)
            "patch": Key(8, POS_INT),  # patch side in px (input_size must divide by it)
            "mlp_ratio": Key(4.0, POS),  # MLP hidden width / dim
            "layerscale": Key(1e-5, num(0, optional=True)),  # LayerScale init value (DINOv2's 1e-5)
            "pos_grid": Key(None, num(1, integer=True, optional=True)),  # side of the position table; None: input grid
            # DINOv2 resizes the position table by (grid + offset) / table: kept for weight parity
            "interpolate_offset": Key(0.1, NN, late=True),
        },
        "resnet": {
            "widths": Key((16, 32, 64, 128), seq(POS_INT)),  # channels per stage
            "blocks": Key((2, 2, 2, 2), seq(POS_INT)),  # basic blocks per stage (as many stages as widths)
            "stem": Key("imagenet", choice("small", "imagenet")),  # imagenet: torchvision's stride-4 stem; small: 3x3
        },
        "regressor": {
            "widths": Key((256, 128, 64, 32), seq(POS_INT)),  # hidden layers of the force MLP
            # output scaled by the training force range (out_scale/out_shift)
            "normalize_output": Key(True, boolean, before=False),
            "out_scale": Key(None, _FORCE3),  # N per unit of output, per axis; None: training fills it from the labels
            "out_shift": Key(None, _FORCE3),  # N, per axis; filled with out_scale
            # BatchNorm on the backbone feature first (docs/training.md)
            "feature_norm": Key(True, boolean, before=False),
        },
        "decoder": {
            "kind": Key("tokens", choice("paper", "tokens")),  # paper: the release's upsample + conv k5; tokens: light
            "channels": Key((32, 16, 16, 8), seq(POS_INT)),  # channels per upsampling stage
            # paper decoder as Dense + pixel shuffle (same function, faster on CPU)
            "fast": Key(True, boolean, late=True),
        },
    },
    "train": {
        "batch_size": Key(64, POS_INT),  # global batch (divisible by the device count)
        "epochs": Key(15, POS_INT),
        # CPU scale trains ~1.4k steps, not the paper's ~150k: higher rates with warmup + cosine decay (in a short
        # run they reached a lower validation Fz error than constant rates of 1e-4 / 5e-4).
        "lr_backbone": Key(5e-4, POS),  # times the method's lr_backbone_scale; 0 when the backbone is frozen
        "lr_heads": Key(1e-3, POS),  # regressor and decoder, times the method's lr_heads_scale
        "schedule": Key("warmup_cosine", choice("constant", "warmup_cosine"), before="constant"),
        "warmup_steps": Key(50, NN_INT, before=0),  # linear warmup of warmup_cosine
        "ckpt_every": Key(200, POS_INT),  # steps between resumable checkpoints (and the last step)
        # validate (and pick the best checkpoint) every this many epochs; the last epoch always validates
        "val_every": Key(1, POS_INT),
        "grad_clip": Key(0.0, NN),  # global gradient-norm clip; 0: none
        # a NaN/inf loss or gradient: "stop" (raise, naming the step and batch) or "skip" (drop that update)
        "nonfinite": Key("stop", choice("stop", "skip")),
        # force term of the loss: "newton" (L1 in N, the release) or "normalized" (each axis / its range)
        "force_loss": Key("normalized", choice("newton", "normalized"), before="newton"),
        # forward/backward precision of the train step: "float32" or "bfloat16" (float32 master weights,
        # float32 losses, optimizer and BatchNorm statistics; evaluation stays float32)
        "compute_dtype": Key("float32", choice("float32", "bfloat16")),
        # LED drift augmentation (ffjax.data.drift): each training frame drifts as the real Mini's LEDs do in up to
        # this many minutes after its background (rates measured on the release's recording at rest); 0: off
        "drift_minutes": Key(0.0, NN, late=True),
    },
    # DINO self-distillation of the backbones (ffjax.train.pretrain, docs/training.md); steps 0: load real
    # weights instead. Sized to stay a small part of a quick run on 2 cores (measured times: docs/training.md).
    "pretrain": {
        "steps": Key(180, NN_INT, before=100),
        "batch_size": Key(32, POS_INT),
        "lr": Key(5e-4, POS),  # peak, after warmup_steps, cosine down to min_lr_ratio * lr
        "corpus_size": Key(6000, NN_INT, before=1000),  # unlabeled images (ffjax.train.pretrain.corpus)
        "out_dim": Key(1024, POS_INT),  # prototypes of the DINO head
        "warmup_steps": Key(20, NN_INT),
        "min_lr_ratio": Key(0.05, PROB),
        "weight_decay": Key(0.04, NN),
        "grad_clip": Key(3.0, NN),
        "head_hidden": Key(512, POS_INT),  # DINO head MLP width
        "head_bottleneck": Key(128, POS_INT),  # L2-normalised bottleneck before the prototypes
        "freeze_last_steps": Key(10, NN_INT),  # the prototype layer stays fixed this many steps
        "init_layerscale": Key(0.1, NN),  # ViT LayerScale at the start of pretraining (1e-5 never leaves uniform)
        "head_bn": Key(True, boolean),  # BatchNorm in the head MLP (without it the teacher stays uniform)
        "local_crops": Key(4, NN_INT),  # multi-crop: local crops per image beside the 2 global ones
        "local_size": Key(32, _PX),  # px
        "global_scale": Key((0.4, 1.0), SCALE),  # area fraction range of a global crop
        "local_scale": Key((0.1, 0.4), SCALE),  # area fraction range of a local crop
        "student_temp": Key(0.1, POS),
        "teacher_temp": Key(0.05, POS, before=0.04),  # after teacher_temp_warmup steps from teacher_temp_start
        "teacher_temp_start": Key(0.04, POS),
        "teacher_temp_warmup": Key(60, NN_INT, before=0),
        "momentum": Key(0.996, PROB),  # teacher EMA momentum at step 0 (cosine to 1)
        "center_momentum": Key(0.9, PROB),  # EMA of the teacher centre
        "flip": Key(0.5, PROB),  # augmentation: flip probability
        "color_jitter": Key(0.4, NN),  # colour and LED-gain jitter strength
        "blur": Key(0.5, PROB),  # probability of a blur
        "noise": Key(0.1, NN),  # pixel noise std
        "corpus_sim_fraction": Key(0.5, PROB),  # share of the corpus from randomised simulated sensors
    },
    # calibration to a new sensor from ~100 samples (ffjax.calibrate)
    "calibrate": {
        "steps": Key(200, NN_INT),
        "lr": Key(1e-4, POS),
        "batch_size": Key(32, POS_INT),
        "holdout": Key(0.2, num(0, 1, hi_open=True)),  # fraction of the samples kept aside to report the error
    },
    # what the experiments' reports say beside their numbers (experiments.tables, experiments.sweep_loss); no cache
    # key holds this section
    "report": {
        # verdict sentences ("... reproduces", "the head helps"); False where the numbers only check the plumbing
        # (smoke): the tables are written, and one sentence says they carry no verdict
        "verdicts": Key(True, boolean),
    },
}

CONFIG = defaults(SPEC)
