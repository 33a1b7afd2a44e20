"""experiments.diagnostics.object_probe: the image signal per shape and a run's read-out (slopes), smoke dataset."""

import json

import numpy as np

from experiments.diagnostics import object_probe


def test_signal_orders_a_wide_flat_face_below_a_small_sphere():
    sig = object_probe.signal(("sphere_small", "wrench"), "mini-1-gel1", size=(24, 32), input_size=32)
    assert sig["sphere_small"]["kind"] == "indenter" and sig["wrench"]["kind"] == "object"
    assert sig["wrench"]["pad_share"] > 2 * sig["sphere_small"]["pad_share"]  # the wrench face covers the view
    assert sig["wrench"]["energy_fz_per_n"] < sig["sphere_small"]["energy_fz_per_n"]
    assert all(v["noise_energy"] > 0 for v in sig.values())


def test_fit_reads_back_a_known_slope_and_offset():
    force = np.random.default_rng(0).uniform(0, 10, (50, 3))
    fit = object_probe._fit(force * [0.5, 1.0, 0.9] + [0, 0, 0.7], force)
    np.testing.assert_allclose(fit["slope"], [0.5, 1.0, 0.9], atol=1e-9)
    assert abs(fit["fz_offset_n"] - 0.7) < 1e-9 and fit["n"] == 50


def test_cli_on_a_smoke_run(tmp_path):
    import shutil

    from _smoke_run import smoke_run

    run = smoke_run()
    data = tmp_path / "data"  # the smoke run's val split, also standing in for one unseen object
    shutil.copytree(run.parent / "data" / "val", data / "val")
    shutil.copytree(run.parent / "data" / "val", data / "unseen" / "wrench")
    res = object_probe.main(["--preset", "smoke", "--data", str(data), "--runs", str(run), "--out",
                             str(tmp_path / "out")])
    out = tmp_path / "out"
    saved = json.loads((out / "results.json").read_text())
    assert set(saved["signal"]) >= {"cube", "wrench"} and saved["commit"]
    readout = res["readout"][str(run)]
    assert set(readout) == {"wrench", "sphere_big"} and all(len(v["slope"]) == 3 for v in readout.values())
    assert readout["wrench"] == readout["sphere_big"]  # the same frames: the same read-out
    assert (out / "object_probe.png").stat().st_size > 10_000
    assert "| wrench | object |" in (out / "object_probe.md").read_text()
