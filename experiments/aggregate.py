"""Tables I-III's numbers: each method's per-seed evaluations aggregated into cells of mean ± std over seeds
(the ablation's and the speed/accuracy chart's results.json)."""

from __future__ import annotations

import numpy as np

from experiments import common
from experiments import paper_numbers as P


def _cell(runs: list[dict]) -> dict:
    """mean/std over seeds of nl1, plus the seeds' mean per-axis MAE in newtons."""
    out = common.mean_std([r["nl1"] for r in runs])
    out["mae_n"] = np.mean([r["mae_n"] for r in runs], axis=0).round(4).tolist()
    out["nl1_axes"] = np.mean([r["nl1_axes"] for r in runs], axis=0).round(3).tolist()
    return out


def aggregate(per_run: dict) -> dict:
    """{method: [eval result per seed]} -> the results.json tables (each cell mean ± std over seeds)."""
    t1, t2, t3 = {}, {}, {}
    for method, runs in per_run.items():
        objs = list(runs[0]["table1"])
        t1[method] = {o: _cell([r["table1"][o] for r in runs]) for o in objs}
        t1[method]["mean"] = common.mean_std([np.mean([r["table1"][o]["nl1"] for o in objs]) for r in runs])
        sensors = list(runs[0]["table2"])
        t2[method] = {P.sensor_label(s): _cell([r["table2"][s] for r in runs]) for s in sensors}
        t2[method]["mean"] = common.mean_std([np.mean([r["table2"][s]["nl1"] for s in P.SENSORS]) for r in runs])
        t3[method] = {}
        for target in runs[0]["table3"]:
            cal = [r["table3"][target] for r in runs]
            t3[method][P.sensor_label(target)] = {
                "layers": cal[0]["layers"],
                "before": _cell([c["before"] for c in cal]),
                "after": _cell([c["after"] for c in cal]),
                "others_before": common.mean_std([c["others_before"] for c in cal]),
                "others_after": common.mean_std([c["others_after"] for c in cal]),
                "degradation_pct": common.mean_std([c["degradation_pct"] for c in cal]),
            }
    return {"table1": t1, "table2": t2, "table3": t3}
