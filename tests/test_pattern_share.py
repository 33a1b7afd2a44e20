"""experiments.pattern_share without training: its scores, its folders, its finding and its figure from made-up
evaluations (the smoke pipeline in test_reproduce runs it end to end)."""

from pathlib import Path

import numpy as np

import configs
from experiments import paper_numbers as P
from experiments import pattern_share as ps


def _eval(shear_by_gel: dict, fz: float = 5.0) -> dict:
    t2 = {s: {"nl1": (2 * shear_by_gel[int(s[-1])] + fz) / 3,
              "nl1_axes": [shear_by_gel[int(s[-1])]] * 2 + [fz]} for s in P.SENSORS}
    return {"table2": t2}


def test_scores_split_the_shear_by_gel():
    got = ps.scores(_eval({1: 6.0, 2: 12.0, 3: 15.0}))
    assert got["shear_gel1"] == 6.0 and got["shear_gel3"] == 15.0 and got["fz_gel2"] == 5.0
    assert np.isclose(got["table2"], np.mean([(2 * v + 5) / 3 for v in (6.0, 12.0, 15.0)]))


def test_each_share_has_its_own_data_folder(tmp_path):
    cfg = configs.get("smoke")
    assert ps.data_folder(cfg, tmp_path / "d", 0.5) == (tmp_path / "d").absolute()  # the preset's share
    assert ps.data_folder(cfg, tmp_path / "d", 0.0) == (tmp_path / "d-pattern0").absolute()


def test_finding_and_figure(tmp_path):
    def cell(gel1, seeds):
        per_seed = [ps.scores(_eval({1: gel1 + 0.3 * k, 2: 12.0 + 0.2 * k, 3: 13.0})) for k in range(seeds)]
        return {"seeds": list(range(seeds)), "run_dirs": [], "per_seed": per_seed,
                **{k: ps.common.mean_std([s[k] for s in per_seed]) for k in ps.METRICS}}

    per_share = {f"{s:g}": {"share": s, "data": "d", "methods": {"dino_rd": cell(g, n)}}
                 for s, g, n in ((0.0, 11.0, 1), (0.5, 8.0, 3), (1.0, 5.0, 1))}
    results = {"preset": "smoke", "commit": "abc", "seeds": [0], "methods": ["dino_rd"], "shares": [0, 0.5, 1],
               "nominal_share": 0.5, "per_share": per_share, "metrics": ps.METRICS, "metric": "nl1 %"}
    results["finding"] = ps.finding(results)
    assert "DINO RD" in results["finding"] and "1: +7.5" in results["finding"]  # gels 2-3 at 12.5 against 5.0
    ps.write_all(results, tmp_path)
    for f in ("pattern_share.md", "pattern_share.csv", "pattern_share.png", "results.json"):
        assert (Path(tmp_path) / f).stat().st_size > 0
    assert "| 0.5 | DINO RD | 3 |" in (tmp_path / "pattern_share.md").read_text()
    # the footer's seeds per cell, not their union over cells of one seed and of three
    assert ps.seeds_said(results) == "0 at shares 0, 1; 0-2 at share 0.5"


def test_shares_read_in_order_whatever_order_they_ran():
    """The run trains the preset's share first (it holds the backbones); tables, finding and figure go by share."""
    def cell(gel1):
        per_seed = [ps.scores(_eval({1: gel1, 2: 7.0, 3: 7.0}))]
        return {"seeds": [0], "run_dirs": [], "per_seed": per_seed,
                **{k: ps.common.mean_std([s[k] for s in per_seed]) for k in ps.METRICS}}

    results = {"per_share": {f"{s:g}": {"share": s, "methods": {"dino_rd": cell(6.0 - s)}} for s in (0.5, 0.0, 1.0)},
               "methods": ["dino_rd"]}
    assert ps._shares(results) == ["0", "0.5", "1"]
    assert "by share: 0: +1.0, 0.5: +1.5, 1: +2.0" in ps.finding(results)
    _, rows, _ = ps._table(results)
    assert [r[0] for r in rows] == ["0", "0.5", "1"]
