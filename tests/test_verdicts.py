"""The smoke preset judges nothing (issue 62): its banner says its numbers only check the plumbing, so its reports
carry no "reproduces" or "the head helps". A property of the preset (config report.verdicts, False in
configs/smoke.py), not of its name; the tables are written all the same. Made-up numbers, no training."""

from __future__ import annotations

import re

import configs
from configs import base
from experiments import common, sweep_loss, tables
from experiments import paper_numbers as P

VERDICT_WORDS = re.compile(r"reproduce|tie\b|not resolved|not measured|\bhelps\b|\bhurts\b|within noise|"
                           r"biased low|One seed", re.IGNORECASE)


def _ablation_results(preset: str) -> dict:
    """An ablation's results.json of two methods, every table filled, at `preset`'s config."""
    c = lambda m, sd=0.2, n=2: {"mean": m, "std": sd, "n": n}  # noqa: E731
    methods = {"dino_rd": 5.0, "dino_r": 6.0, "resnet_rd": 7.0}
    t2 = {m: {"mean": c(v), **{P.sensor_label(k): c(v + i) for i, k in enumerate(P.SENSORS)}}
          for m, v in methods.items()}
    for m, v in methods.items():
        t2[m]["digit"] = c(v + 9)
    t3 = {m: {P.sensor_label(t): {"before": c(v + 4), "after": c(v + 1), "degradation_pct": c(3.0), "layers": "last",
                                  "others_before": c(v), "others_after": c(v + 0.1)}
              for t in P.CALIB_TARGETS} for m, v in methods.items()}
    return {"preset": preset, "config": configs.get(preset), "seeds": [0, 1], "commit": "c" * 40,
            "table1": {m: {"banana": c(v), "mean": c(v)} for m, v in methods.items()}, "table2": t2, "table3": t3}


def test_the_preset_decides_and_the_key_is_documented():
    assert isinstance(base.SPEC["report"]["verdicts"], base.Key) and base.CONFIG["report"]["verdicts"] is True
    assert {p: configs.get(p)["report"]["verdicts"] for p in configs.PRESETS} == \
        {p: p != "smoke" for p in configs.PRESETS}
    assert common.verdicts({"config": configs.get("quick", {"report.verdicts": False})}) is False


def test_smoke_findings_rank_without_a_verdict_and_say_so_once():
    res = _ablation_results("smoke")
    f = tables.findings(res)
    said = [v for k, v in f.items() if k != "note"]
    assert not any(VERDICT_WORDS.search(v) for v in said), said
    assert f["note"] == common.no_verdict(res) and "carry no verdict" in f["note"] and "smoke" in f["note"]
    assert f["table1"].startswith("Table I ranking here (best first): DINO RD 5.0%")
    res["findings"] = f
    summary = tables.console_summary(res)
    assert summary.count("carry no verdict") == 1 and not re.search(r"reproduce|tie, not", summary)
    for fn in (tables.table1_md, tables.table2_md, tables.table3_md):  # the tables are still written
        text, header, rows = fn(res)
        assert rows and not re.search(r"reproduce|tie, not", text), fn.__name__


def test_a_judging_preset_still_judges():
    f = tables.findings(_ablation_results("quick"))
    assert "note" not in f and "reproduces" in f["table1"] and "lowers the target sensor's error" in f["table3"]


def test_an_old_smoke_results_file_without_the_key_judges_nothing():
    """A results.json written before report.verdicts existed: its preset's value today."""
    res = _ablation_results("smoke")
    del res["config"]["report"]
    assert not common.verdicts(res) and "note" in tables.findings(res)
    assert common.verdicts({"config": {}}) and common.verdicts({"preset": "no-such-preset"})


def test_smoke_sweep_finding_has_numbers_and_no_verdict():
    def cell(beta, mean, std, n, name):
        ms = {"mean": mean, "std": std, "n": n}
        return {"beta": beta, "ratio": beta, "per_seed": [{}] * n, "paper_name": name,
                **{m: ms for m in sweep_loss.METRICS}}

    cells = {"0": cell(0.0, 5.0, 0.1, 3, "DINO R"), "10": cell(10.0, 5.4, 0.1, 3, "DINO RD"),
             "1": cell(1.0, 4.9, 0.0, 1, "b1"), "3": cell(3.0, 5.2, 0.0, 1, "b3")}
    smoke = {"base": "dino_rd", "per_beta": cells, "preset": "smoke", "config": configs.get("smoke")}
    text = sweep_loss.finding(smoke)
    assert "no head reads 5.00 ± 0.10%" in text and "beta/alpha = 10 5.40 ± 0.10%" in text
    assert text.count("carry no verdict") == 1
    assert not VERDICT_WORDS.search(text.replace(common.no_verdict(smoke), "")), text
    judged = sweep_loss.finding({**smoke, "preset": "quick", "config": configs.get("quick")})
    assert "the head hurts" in judged and "carry no verdict" not in judged
