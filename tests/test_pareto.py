"""experiments.pareto: the Pareto front on hand-made points, and a smoke run (2 sizes x 1 method) that writes
every file with positive, finite numbers. No timed assertions: the machine is shared."""

import json
import math

import pytest

from experiments import pareto

# No pretraining in the smoke run (it would double the test's time); test_backbone_folder_per_size covers
# how a pretrained method gets its size's backbone.
METHOD = "dino_rd_scratch"


def test_front_minimizes_both_axes():
    pts = [(1, 5), (2, 3), (3, 4), (4, 1), (2, 3.5), (5, 1)]
    assert pareto.pareto_front(pts) == [0, 1, 3]


def test_front_maximizes_x_when_asked_and_skips_nan():
    # (throughput, error): more throughput and less error are better
    pts = [(100, 5), (50, 2), (80, 6), (100, 5.5), (float("nan"), 0.1), (10, 2)]
    assert pareto.pareto_front(pts, (False, True)) == [0, 1]


def test_front_keeps_ties_and_handles_empty():
    assert pareto.pareto_front([(1, 1), (1, 1), (2, 2)]) == [0, 1]
    assert pareto.pareto_front([]) == []


def test_lean_grid_trains_all_methods_only_at_the_presets_size():
    cfg = {"preset": "quick"}
    cells = pareto.grid(cfg, ["resnet_rd", "dino_r", "dino_rd"], ["vit-xs", "vit-s", "resnet"])
    assert cells == [("vit-xs", "dino_rd"), ("vit-s", "dino_r"), ("vit-s", "dino_rd"), ("resnet", "resnet_rd")]
    full = pareto.grid(cfg, ["dino_r", "dino_rd"], ["vit-xs", "vit-m"], full=True)
    assert len(full) == 4


def test_size_cfg_overrides_only_the_backbone():
    import configs

    cfg = configs.get("quick")
    m = pareto.size_cfg(cfg, "vit-m")["model"]
    assert (m["vit"]["dim"], m["vit"]["depth"], m["vit"]["patch"]) == (128, 4, cfg["model"]["vit"]["patch"])
    assert m["resnet"] == cfg["model"]["resnet"] and cfg["model"]["vit"]["dim"] == 64


def test_backbone_folder_per_size(tmp_path, monkeypatch):
    import configs
    from ffjax import registry
    from ffjax.train import pretrain

    calls = []
    monkeypatch.setattr(pretrain, "ensure", lambda cfg, kind, folder, **kw: calls.append((cfg, kind, folder)))
    monkeypatch.setattr(pretrain, "load_backbone", lambda folder, kind=None: ("params", folder))
    cfg, spec = configs.get("smoke"), registry.get("dino_rd")
    folders = set()
    for size in ("vit-xs", "vit-m"):
        scfg = pareto.size_cfg(cfg, size)
        assert pareto.backbone_for(cfg, scfg, size, spec, tmp_path, False, False) == ("params", calls[-1][2])
        assert calls[-1][0] is scfg and calls[-1][1] == "vit"
        folders.add(calls[-1][2])
    assert len(folders) == 2 and all(f.parent == tmp_path / "pretrained" for f in folders)
    assert tmp_path / "pretrained" / "vit" not in folders  # the preset's own (the ablation's) stays apart
    assert pareto.backbone_for(cfg, cfg, "vit-s", registry.get("dino_rd_scratch"), tmp_path, False, False) is None


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    root = tmp_path_factory.mktemp("pareto")
    out = root / "out"
    # its own data folder: tests never write into the user's data/smoke
    pareto.main(["--preset", "smoke", "--methods", METHOD, "--sizes", "vit-xs", "vit-s", "--out", str(out),
                 "--ablation", "none", "--data", str(root / "data"), "--quiet"])
    return out


def test_smoke_run_writes_files_with_finite_numbers(smoke):
    for name in ("results.json", "pareto.md", "pareto.csv", "pareto.png"):
        assert (smoke / name).stat().st_size > 0, name
    res = json.loads((smoke / "results.json").read_text())
    assert res["preset"] == "smoke" and res["seeds"] == [0] and "commit" in res
    assert {"cpu_model", "loadavg_before", "loadavg_after", "steal"} <= set(res["machine"])
    assert [c["label"] for c in res["cells"]] == [f"{METHOD}@vit-xs", f"{METHOD}@vit-s"]
    for c in res["cells"]:
        for k in ("latency_b1_ms", "latency_b32_ms", "train_img_s", "b32_img_s", "params_total", "params_trainable"):
            assert c[k] > 0 and math.isfinite(c[k]), (c["label"], k)
        assert 0 < c["table1"]["mean"] < 1e3 and 0 < c["table2"]["mean"] < 1e3
    small, big = res["cells"]
    assert small["params_total"] < big["params_total"]
    assert set(res["fronts"]) == {p[0] for p in pareto.PANELS} and all(res["fronts"].values())
    assert f"{METHOD}@vit-s" in (smoke / "pareto.md").read_text()
    assert len((smoke / "pareto.csv").read_text().strip().splitlines()) == 3
