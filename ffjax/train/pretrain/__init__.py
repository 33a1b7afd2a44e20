"""Self-supervised pretraining of CPU-scale backbones: DINO self-distillation on an unlabeled corpus.

Real DINOv2 / ImageNet weights are out of reach here, so the "pretrained" ViT and ResNet of the ablation
get their features from DINO (Caron et al. 2021): a student and an EMA teacher copy of the backbone, each
with a projection head (MLP -> L2-normalized bottleneck -> weight-normed prototypes); the student matches
the teacher's centred, sharpened distribution across multi-crop views. The corpus holds procedural images
and frames of randomized simulated sensors, never the evaluation sensors' labelled data.

    python -m ffjax.train.pretrain --preset quick --backbone vit|resnet|all --out DIR [--force] [--probe]
    pretrain.ensure(cfg, "vit", "DIR/vit")               # pretrain unless a matching cache is there
    params, batch_stats = pretrain.load_backbone("DIR/vit")   # -> params["backbone"] of the force model

DIR/<kind>/ holds backbone.msgpack (the teacher's backbone, flax.serialization), pretrain.json (the
config it was made from + final metrics), log.jsonl, and probe.json when probed. The corpus is cached
once in DIR/<kind>/.. as corpus_<hash>.npy. A rerun with a matching config reuses the cache.

Files: model.py (DINO head and model), augment.py (multi-crop views), update.py (loss, schedules, the
jitted step), corpus.py (the unlabeled images), cache.py (settings = cache key, save / load), loop.py
(ensure, pretrain: the run), report.py (linear probe), __main__.py (the CLI).
"""

from ffjax.train.pretrain import corpus
from ffjax.train.pretrain.augment import augment_view, multicrop
from ffjax.train.pretrain.cache import (
    BACKBONE_FILE,
    META_FILE,
    VERSION,
    is_cached,
    load_backbone,
    run_dir,
    save_backbone,
    settings,
)
from ffjax.train.pretrain.loop import COMPILER_OPTIONS, ensure, pretrain
from ffjax.train.pretrain.model import DINO, KINDS, DINOHead, build
from ffjax.train.pretrain.report import feature_health, features, format_report, linear_probe, probe_report
from ffjax.train.pretrain.update import dino_loss, init_state, make_optimizer, make_update, schedules

__all__ = [
    "BACKBONE_FILE",
    "COMPILER_OPTIONS",
    "DINO",
    "KINDS",
    "META_FILE",
    "VERSION",
    "DINOHead",
    "augment_view",
    "build",
    "corpus",
    "dino_loss",
    "ensure",
    "feature_health",
    "features",
    "format_report",
    "init_state",
    "is_cached",
    "linear_probe",
    "load_backbone",
    "make_optimizer",
    "make_update",
    "multicrop",
    "pretrain",
    "probe_report",
    "run_dir",
    "save_backbone",
    "schedules",
    "settings",
]
