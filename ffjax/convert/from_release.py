"""The FeelAnyForce release checkpoint (`checkpoint_v1.pth.tar`) -> ffjax ForceModel variables.

The release (prgumd/FeelAnyForce, training_multi_head.py) saves
`{"epoch", "state_dict", "optimizer", "best_val_loss", "config": vars(args)}`; its state dict is a
ComposedModel's:
  tactile_backbone.*                         torch-hub DINOv2 ViT-B/14   -> params/backbone (from_dinov2.py)
  regressor.regressor.{3i}.weight_g/_v/bias  weight-normed Linear i      -> params/regressor/fc_i/{g,v,bias}
  regressor.regressor.{3i+1}.weight/bias     LayerNorm i                 -> params/regressor/norm_i
  regressor.regressor.{3n}.*                 final Linear(64->3)         -> params/regressor/out
  regressor.bottleneck{i+1}.*, regressor.linear.*   the same Linears again (the Regressor registers them
                                                    twice); must equal their Sequential copies
  decoder.fc.weight/bias                     plain Linear                -> params/decoder/fc (v = W.T,
                                                                            g = its column norms: same W)
  decoder.deconvs.{j}.weight/bias            Conv2d k5                   -> params/decoder/conv_j
The release decoder ends in 3 output channels (all trained toward the same depth map); ours has one:
`depth_channel` picks which of the three is kept (default 0). The optimizer state is never read.
"""

from __future__ import annotations

import math
import re

import jax
import jax.numpy as jnp
import numpy as np

from ..models import heads as heads_lib
from ..models import model as model_lib
from ..models import vit as vit_lib
from ..store import converted
from . import from_dinov2, kinds, mapping, reader
from .mapping import conv, identity, linear

BACKBONE_PREFIXES = ("tactile_backbone.", "backbone.", "encoder.")


def gain(x: np.ndarray) -> np.ndarray:
    """torch weight_norm(dim=0) weight_g (out, 1) -> (out,)."""
    return x.reshape(x.shape[0])


def _wn_rules(src: str, dst: str) -> list[mapping.Rule]:
    return [
        (src + r"\.weight_g", dst + "/g", gain),
        (src + r"\.weight_v", dst + "/v", linear),
        (src + r"\.bias", dst + "/bias", identity),
    ]


def table(n_layers: int, backbone_prefix: str, depth_channel: int = 0, with_decoder: bool = True):
    """The release's mapping for a regressor of `n_layers` bottlenecks (paper: 4)."""
    rules: list[mapping.Rule] = []
    bp = re.escape(backbone_prefix)
    for pattern, target, fn in from_dinov2.TABLE:
        rules.append((bp + pattern, None if target is None else "params/backbone/" + target, fn))
    for i in range(n_layers):
        for src in (rf"regressor\.regressor\.{3 * i}", rf"regressor\.bottleneck{i + 1}"):
            rules += _wn_rules(src, f"params/regressor/fc_{i}")
        rules += [
            (rf"regressor\.regressor\.{3 * i + 1}\.weight", f"params/regressor/norm_{i}/scale", identity),
            (rf"regressor\.regressor\.{3 * i + 1}\.bias", f"params/regressor/norm_{i}/bias", identity),
        ]
    for src in (rf"regressor\.regressor\.{3 * n_layers}", r"regressor\.linear"):
        rules += _wn_rules(src, "params/regressor/out")
    if not with_decoder:
        return [*rules, (r"decoder\..*", None, identity)]
    ch = slice(depth_channel, depth_channel + 1)
    rules += [
        *_wn_rules(r"decoder\.fc", "params/decoder/fc"),
        (r"decoder\.deconvs\.3\.weight", "params/decoder/conv_3/kernel", lambda w: conv(w[ch])),
        (r"decoder\.deconvs\.3\.bias", "params/decoder/conv_3/bias", lambda b: b[ch]),
        (r"decoder\.deconvs\.([0-2])\.weight", r"params/decoder/conv_\1/kernel", conv),
        (r"decoder\.deconvs\.([0-2])\.bias", r"params/decoder/conv_\1/bias", identity),
    ]
    return rules


def _normalize(state: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Bring Linears to the weight_g / weight_v form: the new parametrization API's names
    (`parametrizations.weight.original0/1`) are renamed, and a plain `decoder.fc.weight` is written as
    v = W, g = row norms of W (the same weight: our decoder's first Linear is weight-normed)."""
    out = {}
    for k, v in state.items():
        k = k.replace(".parametrizations.weight.original0", ".weight_g")
        k = k.replace(".parametrizations.weight.original1", ".weight_v")
        out[k] = v
    if "decoder.fc.weight" in out:
        w = out.pop("decoder.fc.weight")
        out["decoder.fc.weight_v"] = w
        out["decoder.fc.weight_g"] = np.linalg.norm(w.astype(np.float64), axis=1, keepdims=True).astype(w.dtype)
    return out


def _backbone_prefix(state, source) -> str:
    for p in BACKBONE_PREFIXES:
        if p + "patch_embed.proj.weight" in state:
            return p
    raise mapping.ConversionError(source, {"its DINOv2 backbone is under none of the release's prefixes":
                                           [", ".join(BACKBONE_PREFIXES)]})


def infer_config(state, config: dict, heads: int | None, source: str) -> tuple[dict, int, str]:
    """(cfg["model"] sections, input_size, backbone prefix) read off the release state dict and its saved args."""
    kinds.check(state, "feelanyforce", source)
    prefix = _backbone_prefix(state, source)
    backbone_state, _ = mapping.fold_prefix(state, prefix)
    if heads is None:
        name = str(config.get("tactile_model", ""))
        heads = next((h for k, h in from_dinov2.HUB_HEADS.items() if k in name), None)
    cfg_vit = from_dinov2.infer_config(backbone_state, heads, source)
    n = 0
    while f"regressor.regressor.{3 * n}.weight_v" in state and f"regressor.regressor.{3 * n + 1}.weight" in state:
        n += 1
    widths = tuple(int(state[f"regressor.regressor.{3 * i}.weight_v"].shape[0]) for i in range(n))
    if n and state["regressor.regressor.0.weight_v"].shape[1] != cfg_vit["dim"]:
        shape = state["regressor.regressor.0.weight_v"].shape
        why = "regressor input is not the CLS feature (release args forward=False / n_last_blocks / avgpool?)"
        raise mapping.ConversionError(
            source, {why: [f"regressor.regressor.0.weight_v {shape}, backbone dim {cfg_vit['dim']}"]}
        )
    cfg = {"vit": cfg_vit, "regressor": {"widths": widths}}
    size = int(config.get("crop_size", 224))
    if "decoder.fc.weight_v" in state:
        channels = tuple(int(state[f"decoder.deconvs.{j}.weight"].shape[1]) for j in range(4))
        side = math.isqrt(state["decoder.fc.weight_v"].shape[0] // channels[0])
        if math.ceil(size / 16) != side:
            size = 16 * side
        cfg["decoder"] = {"kind": "paper", "channels": channels}
    return cfg, size, prefix


def expected_variables(cfg: dict, size: int) -> dict:
    decoder = heads_lib.PaperDecoder(tuple(cfg["decoder"]["channels"]), size) if "decoder" in cfg else None
    net = model_lib.ForceModel(
        backbone=vit_lib.from_config(cfg["vit"]),
        regressor=heads_lib.Regressor(tuple(cfg["regressor"]["widths"])),
        decoder=decoder,
    )
    return jax.eval_shape(net.init, jax.random.PRNGKey(0), jnp.zeros((1, size, size, 3)))


def convert_state(
    state: dict[str, np.ndarray],
    config: dict | None = None,
    heads: int | None = None,
    depth_channel: int = 0,
    with_decoder: bool = True,
    source: str = "",
) -> tuple[dict, dict, int]:
    """A flat release state dict (+ its saved args) -> (cfg["model"], variables, input_size)."""
    state = _normalize(state)
    cfg, size, prefix = infer_config(state, config or {}, heads, source)
    if not with_decoder:
        cfg.pop("decoder", None)
    rules = table(len(cfg["regressor"]["widths"]), prefix, depth_channel, with_decoder)
    variables = mapping.apply(rules, state, expected_variables(cfg, size), source)
    return cfg, variables, size


def release_config(obj) -> dict:
    """The training args the release saves beside its weights ({} when absent)."""
    config = obj.get("config", {}) if isinstance(obj, dict) else {}
    return config if isinstance(config, dict) else {}


def convert_file(
    path, heads: int | None = None, depth_channel: int = 0, with_decoder: bool = True
) -> tuple[dict, dict, int]:
    """The release checkpoint file -> (the cfg["model"] sections its weights decide, variables, input_size): what
    `python -m ffjax.convert feelanyforce` saves (ffjax.store.converted)."""
    obj = reader.load(path)
    return convert_state(
        reader.state_dict(obj, path), release_config(obj), heads, depth_channel, with_decoder, str(path)
    )


def feelanyforce(
    path, heads: int | None = None, depth_channel: int = 0, with_decoder: bool = True
) -> tuple[dict, dict]:
    """Convert the FeelAnyForce release checkpoint -> (cfg["model"], variables):

        cfg, variables = convert.feelanyforce("checkpoint_v1.pth.tar")
        model = models.build(cfg, registry.get("dino_rd"), 224)     # 224: the release's crop_size
        out = model.apply(variables, images)                         # images (B, 224, 224, 3), normalized

    cfg is complete (the paper preset's model section with the weights' sizes and the release's regressor head,
    as `ffjax.store.load` builds a converted folder); variables = {"params": {"backbone", "regressor",
    ["decoder"]}}. heads: ViT heads (default from the saved args' tactile_model, e.g. dinov2_vitb14 -> 12, else
    dim // 64). depth_channel: which of the release decoder's 3 output channels becomes our single depth channel.
    with_decoder=False drops it (for methods without a depth head: registry.get("dino_r")).
    """
    sections, variables, _ = convert_file(path, heads, depth_channel, with_decoder)
    return converted.release_model(sections), variables
