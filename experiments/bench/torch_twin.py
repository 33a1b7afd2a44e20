"""The PyTorch side of `experiments.bench`: the same architectures as ffjax, timed the same way.

Self-contained (torch + numpy only, no ffjax import) so it also runs as a subprocess under another
interpreter: `python experiments/bench/torch_twin.py --serve` answers one JSON request per stdin line with one
JSON line (requests: {"op": "info"}, {"op": "peak", "n": 2048}, {"op": "train"|"infer", "arch": {...},
"batch": B, "warmup": w, "steps": k, "rounds": r}; any request may add "device": "cuda" and, for train/infer,
"compile": true for torch.compile). `arch` is what `experiments.bench.arch_of` writes:
backbone "vit"|"resnet" with its config, regressor widths, decoder {kind, channels} or None, input_size,
beta. Needs the optional extra: `pip install torch==2.13.0` (CPU build).
"""

from __future__ import annotations

import json
import math
import statistics
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

THREADS = 2


# ---------------------------------------------------------------- models (mirror ffjax.models)
class WNLinear(nn.Module):
    """torch weight_norm(Linear, dim=0) as the release uses it: weight = g * v / ||v|| per output row."""

    def __init__(self, fan_in: int, fan_out: int):
        super().__init__()
        lin = nn.Linear(fan_in, fan_out)
        self.v = nn.Parameter(lin.weight.detach().clone())
        self.g = nn.Parameter(lin.weight.detach().norm(dim=1, keepdim=True))
        self.bias = nn.Parameter(lin.bias.detach().clone())

    def forward(self, x):
        return F.linear(x, self.g * self.v / self.v.norm(dim=1, keepdim=True), self.bias)


class Regressor(nn.Module):
    def __init__(self, dim: int, widths, feature_norm: bool = False):
        super().__init__()
        layers, d = [nn.BatchNorm1d(dim, eps=1e-5, momentum=0.1)] if feature_norm else [], dim
        for w in widths:
            layers += [WNLinear(d, w), nn.LayerNorm(w, eps=1e-5), nn.GELU()]
            d = w
        self.body, self.out = nn.Sequential(*layers), WNLinear(d, 3)

    def forward(self, x):
        return self.out(self.body(x))


class Block(nn.Module):
    def __init__(self, dim, heads, mlp_ratio, ls):
        super().__init__()
        self.heads = heads
        self.norm1, self.norm2 = nn.LayerNorm(dim, eps=1e-6), nn.LayerNorm(dim, eps=1e-6)
        self.qkv, self.proj = nn.Linear(dim, 3 * dim), nn.Linear(dim, dim)
        hidden = int(dim * mlp_ratio)
        self.fc1, self.fc2 = nn.Linear(dim, hidden), nn.Linear(hidden, dim)
        self.ls1, self.ls2 = nn.Parameter(torch.full((dim,), ls)), nn.Parameter(torch.full((dim,), ls))

    def forward(self, x):
        b, n, d = x.shape
        qkv = self.qkv(self.norm1(x)).reshape(b, n, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        y = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2])  # torch's fast path (DINOv2 / HF sdpa)
        x = x + self.ls1 * self.proj(y.transpose(1, 2).reshape(b, n, d))
        return x + self.ls2 * self.fc2(F.gelu(self.fc1(self.norm2(x))))


class ViT(nn.Module):
    """DINOv2 layout: patch conv, CLS + learned positions (bicubic-interpolated when the grid differs)."""

    def __init__(self, dim, depth, heads, patch, mlp_ratio=4.0, layerscale=1e-5, pos_grid=None, input_size=64,
                 **_):
        super().__init__()
        self.patch, self.grid = patch, input_size // patch
        self.pos_grid = pos_grid or self.grid
        self.patch_embed = nn.Conv2d(3, dim, patch, patch)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, dim))
        self.pos_embed = nn.Parameter(torch.randn(1, 1 + self.pos_grid**2, dim) * 0.02)
        self.blocks = nn.ModuleList(Block(dim, heads, mlp_ratio, layerscale) for _ in range(depth))
        self.norm = nn.LayerNorm(dim, eps=1e-6)
        self.dim = dim

    def _pos(self, h, w):
        if (h, w) == (self.pos_grid, self.pos_grid):
            return self.pos_embed
        m = self.pos_grid
        patch = self.pos_embed[:, 1:].reshape(1, m, m, -1).permute(0, 3, 1, 2)
        patch = F.interpolate(patch, scale_factor=((h + 0.1) / m, (w + 0.1) / m), mode="bicubic")
        return torch.cat([self.pos_embed[:, :1], patch.permute(0, 2, 3, 1).reshape(1, h * w, -1)], 1)

    def forward(self, x):
        x = self.patch_embed(x)
        b, d, h, w = x.shape
        x = x.flatten(2).transpose(1, 2)
        x = torch.cat([self.cls_token.expand(b, -1, -1), x], 1) + self._pos(h, w)
        for blk in self.blocks:
            x = blk(x)
        x = self.norm(x)
        return x[:, 0], x[:, 1:].reshape(b, h, w, d)


class BasicBlock(nn.Module):
    def __init__(self, cin, cout, stride):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.down = None
        if stride != 1 or cin != cout:
            self.down = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x):
        y = self.bn2(self.conv2(F.relu(self.bn1(self.conv1(x)))))
        return F.relu((x if self.down is None else self.down(x)) + y)


class ResNet(nn.Module):
    """torchvision ResNet-18 layout, widths/blocks/stem from the config (as ffjax.models.resnet).

    stem "imagenet": conv 7x7 s2 + maxpool (stride 4); "small": conv 3x3 s1, no maxpool.
    """

    def __init__(self, widths, blocks, stem="imagenet", **_):
        super().__init__()
        if stem == "imagenet":
            self.stem = nn.Sequential(nn.Conv2d(3, widths[0], 7, 2, 3, bias=False), nn.BatchNorm2d(widths[0]),
                                      nn.ReLU(), nn.MaxPool2d(3, 2, 1))
        elif stem == "small":
            self.stem = nn.Sequential(nn.Conv2d(3, widths[0], 3, 1, 1, bias=False), nn.BatchNorm2d(widths[0]),
                                      nn.ReLU())
        else:
            raise ValueError(f"unknown ResNet stem {stem!r}")
        layers, cin = [], widths[0]
        for i, (w, n) in enumerate(zip(widths, blocks)):
            for j in range(n):
                layers.append(BasicBlock(cin, w, 2 if (i > 0 and j == 0) else 1))
                cin = w
        self.layers = nn.Sequential(*layers)
        self.dim = widths[-1]

    def forward(self, x):
        x = self.layers(self.stem(x))
        return x.mean((2, 3)), x.permute(0, 2, 3, 1)


def _fit(x, size):
    if x.shape[-1] == size and x.shape[-2] == size:
        return x
    return F.interpolate(x, size=(size, size), mode="bilinear", antialias=True, align_corners=False)


class TokenDecoder(nn.Module):
    """1x1 projection then per-pixel Linear(4C) + pixel shuffle stages (ffjax.models.heads.TokenDecoder)."""

    def __init__(self, dim, channels, out_size, grid):
        super().__init__()
        self.n = max(1, math.ceil(math.log2(out_size / grid) - 1e-9))
        self.out_size = out_size
        self.proj = nn.Linear(dim, channels[0])
        ups, c_in = [], channels[0]
        for i in range(self.n):
            c = 1 if i == self.n - 1 else channels[min(i + 1, len(channels) - 1)]
            ups.append(nn.Linear(c_in, 4 * c))
            c_in = c
        self.ups = nn.ModuleList(ups)

    def forward(self, feature, tokens):
        b, h, w, _ = tokens.shape
        x = self.proj(tokens)
        for up in self.ups:
            x = up(F.relu(x))
            x = x.reshape(*x.shape[:-1], 2, 2, x.shape[-1] // 4)
        dys = [3 + 2 * i for i in range(self.n)]
        x = x[..., 0].permute(0, 1, *dys, 2, *[d + 1 for d in dys]).reshape(b, 1, h * 2**self.n, w * 2**self.n)
        return F.leaky_relu(_fit(x, self.out_size), 0.01)[:, 0]


class PaperDecoder(nn.Module):
    """The release's decoder: WN Linear -> (C0,b,b), 4 x (nearest x2 + conv k5), LeakyReLU."""

    def __init__(self, dim, channels, out_size):
        super().__init__()
        self.b, self.c0, self.out_size = math.ceil(out_size / 16), channels[0], out_size
        self.fc = WNLinear(dim, self.c0 * self.b * self.b)
        outs = (*channels[1:], 1)
        cins = channels
        self.convs = nn.ModuleList(nn.Conv2d(ci, co, 5, 1, 2) for ci, co in zip(cins, outs))

    def forward(self, feature, tokens):
        x = F.relu(self.fc(feature)).reshape(-1, self.c0, self.b, self.b)
        for i, conv in enumerate(self.convs):
            x = conv(F.interpolate(x, scale_factor=2, mode="nearest"))
            x = F.relu(x) if i < len(self.convs) - 1 else x
        return F.leaky_relu(_fit(x, self.out_size), 0.01)[:, 0]


class ForceModel(nn.Module):
    def __init__(self, arch: dict):
        super().__init__()
        s = arch["input_size"]
        if arch["backbone"] == "vit":
            self.backbone = ViT(input_size=s, **arch["vit"])
            grid = s // arch["vit"]["patch"]
        else:
            self.backbone = ResNet(**arch["resnet"])
            grid = math.ceil(s / (8 if arch["resnet"].get("stem") == "small" else 32))  # the backbone's stride
        dim = self.backbone.dim
        self.regressor = Regressor(dim, arch["regressor"], arch.get("feature_norm", False))
        dec = arch.get("decoder")
        self.decoder = None
        if dec:
            self.decoder = (PaperDecoder(dim, dec["channels"], s) if dec["kind"] == "paper"
                            else TokenDecoder(dim, dec["channels"], s, grid))

    def forward(self, x, depth: bool = True):
        feature, tokens = self.backbone(x)
        out = {"force": self.regressor(feature)}
        if depth and self.decoder is not None:
            out["depth"] = self.decoder(feature, tokens)
        return out


# ---------------------------------------------------------------- timing
def _device(req: dict) -> torch.device:
    """req["device"]: "cpu" (default) or "cuda". On CUDA float32 matmuls and convs run in TF32, which is what
    XLA's default precision does on the same GPU, so both sides are timed at the same precision."""
    dev = torch.device(req.get("device", "cpu"))
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise RuntimeError("device cuda requested but torch.cuda.is_available() is False")
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    return dev


def _synced(fn, dev: torch.device):
    """fn followed by a device sync: CUDA kernels run asynchronously, a timer must wait for them."""
    if dev.type != "cuda":
        return fn

    def run():
        out = fn()
        torch.cuda.synchronize(dev)
        return out

    return run


def _median_ms(fn, warmup: int, steps: int, rounds: int) -> tuple[float, list[float]]:
    for _ in range(warmup):
        fn()
    per = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(steps):
            fn()
        per.append((time.perf_counter() - t0) / steps * 1e3)
    return statistics.median(per), per


def _first_call_s(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def count_params(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


def measure_train(arch: dict, batch: int, warmup: int, steps: int, rounds: int, lrs=(1e-4, 5e-4),
                  device: str = "cpu", compile: bool = False) -> dict:
    """Adam (backbone lr, heads lr), loss = L1(force) + beta * MSE(depth): one step = fwd + bwd + update.
    compile=True runs the model under torch.compile (its first call, compile_s, pays the compilation)."""
    torch.manual_seed(0)
    dev = _device({"device": device})
    model = ForceModel(arch).train().to(dev)
    fwd = torch.compile(model) if compile else model
    s = arch["input_size"]
    x = torch.randn(batch, 3, s, s, device=dev)
    f = torch.randn(batch, 3, device=dev)
    d = torch.rand(batch, s, s, device=dev)
    heads = [p for n, p in model.named_parameters() if not n.startswith("backbone.")]
    opt = torch.optim.Adam([{"params": model.backbone.parameters(), "lr": lrs[0]}, {"params": heads, "lr": lrs[1]}])
    beta = float(arch.get("beta", 0.0))

    def step():
        opt.zero_grad(set_to_none=True)
        out = fwd(x)
        loss = F.l1_loss(out["force"], f)
        if beta and "depth" in out:
            loss = loss + beta * F.mse_loss(out["depth"], d)
        loss.backward()
        opt.step()
        return loss

    step = _synced(step, dev)
    compile_s = _first_call_s(step)
    ms, per = _median_ms(step, warmup, steps, rounds)
    return {"ms": ms, "ms_rounds": per, "img_s": batch / ms * 1e3, "params": count_params(model), "batch": batch,
            "device": str(dev), "mode": "compile" if compile else "eager", "compile_s": compile_s}


def measure_infer(arch: dict, batch: int, warmup: int, steps: int, rounds: int, device: str = "cpu",
                  compile: bool = False) -> dict:
    """Force only (what a control loop needs: the depth head is not run), eval mode, inference_mode."""
    torch.manual_seed(0)
    dev = _device({"device": device})
    model = ForceModel(arch).eval().to(dev)
    fwd = torch.compile(model) if compile else model
    s = arch["input_size"]
    x = torch.randn(batch, 3, s, s, device=dev)
    with torch.inference_mode():
        run = _synced(lambda: fwd(x, depth=False), dev)
        compile_s = _first_call_s(run)
        ms, per = _median_ms(run, warmup, steps, rounds)
    return {"ms": ms, "ms_rounds": per, "img_s": batch / ms * 1e3, "params": count_params(model), "batch": batch,
            "device": str(dev), "mode": "compile" if compile else "eager", "compile_s": compile_s}


def matmul_peak(n: int = 2048, rounds: int = 5, device: str = "cpu") -> dict:
    dev = _device({"device": device})
    a, b = torch.randn(n, n, device=dev), torch.randn(n, n, device=dev)
    ms, per = _median_ms(_synced(lambda: a @ b, dev), 1, 1, rounds)
    return {"n": n, "ms": ms, "gflops": 2 * n**3 / (min(per) * 1e-3) / 1e9,
            "gflops_median": 2 * n**3 / (ms * 1e-3) / 1e9, "device": str(dev)}


def handle(req: dict) -> dict:
    torch.set_num_threads(int(req.get("threads", THREADS)))
    op, device = req["op"], req.get("device", "cpu")
    if op == "info":
        out = {"torch": torch.__version__, "threads": torch.get_num_threads(), "numpy": np.__version__,
               "cuda": torch.cuda.is_available()}
        if torch.cuda.is_available():
            out["cuda_device"] = torch.cuda.get_device_name(0)
        return out
    if op == "peak":
        return matmul_peak(int(req.get("n", 2048)), int(req.get("rounds", 5)), device)
    fn = {"train": measure_train, "infer": measure_infer}[op]
    return fn(req["arch"], int(req["batch"]), int(req.get("warmup", 2)), int(req.get("steps", 3)),
              int(req.get("rounds", 3)), device=device, compile=bool(req.get("compile", False)))


def serve() -> None:
    """One JSON request per stdin line -> one JSON line on stdout (errors answered, not raised)."""
    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            out = handle(json.loads(line))
        except Exception as e:  # noqa: BLE001 - the parent reports it, the server keeps going
            out = {"error": f"{type(e).__name__}: {e}"}
        sys.stdout.write(json.dumps(out) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    if "--serve" in sys.argv:
        serve()
    else:
        print(json.dumps(handle(json.loads(sys.argv[1]) if len(sys.argv) > 1 else {"op": "info"})))
