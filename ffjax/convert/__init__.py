"""PyTorch state dicts -> Flax params, without torch.

    vit_cfg, params = convert.dinov2("dinov2_vitb14_pretrain.pth")          # torch-hub DINOv2
    resnet_cfg, params, batch_stats = convert.resnet18("resnet18-f37072fd.pth")   # torchvision
    model_cfg, variables = convert.feelanyforce("checkpoint_v1.pth.tar")    # the FeelAnyForce release, complete:
    model = models.build(model_cfg, registry.get("dino_rd"), 224)           #   cfg["model"] for its crop size
    python -m ffjax.convert {dinov2,resnet18,feelanyforce} IN --out DIR ;  convert.load(DIR)

Files: .safetensors, or .pth / .pth.tar / .pt written by torch.save, read by an allow-list unpickler
(tensors, storages, OrderedDict, primitives only; like torch.load(weights_only=True)). Each converter is a
regex table (TABLE in from_dinov2 / from_torchvision, table() in from_release) from torch names to Flax
paths; every tensor is shape-checked against the Flax model and all problems are reported in one
ConversionError. A file of another kind (a DINOv2 file given to resnet18) is refused in one line naming what it
holds and the converter that reads it (kinds.py).
"""

from ffjax.errors import UnsafePickleError
from ffjax.store.converted import load, load_backbone, save

from .from_dinov2 import dinov2
from .from_release import feelanyforce
from .from_torchvision import resnet18
from .mapping import ConversionError
from .reader import MissingExtraError, read_state_dict

__all__ = [
    "ConversionError",
    "MissingExtraError",
    "UnsafePickleError",
    "dinov2",
    "feelanyforce",
    "load",
    "load_backbone",
    "read_state_dict",
    "resnet18",
    "save",
]
