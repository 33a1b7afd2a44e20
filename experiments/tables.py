"""Tables I-III drawn from an ablation's results.json: the findings (verdict sentences), markdown, CSV and plots.
The numbers they show are experiments.aggregate's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from experiments import common, style
from experiments import paper_numbers as P


def _m(x) -> float:
    return float(x["mean"]) if isinstance(x, dict) else float("nan")


_name = style.name


TIE_FLOOR = 0.05  # points: below the tables' 0.1 resolution a difference is not one, whatever the seeds


def _noise(*cells) -> float:
    """The seed noise of a difference between cells: their stds combined (0 with one seed), at least TIE_FLOOR."""
    stds = [float(c.get("std", 0.0)) if _seeds(c) > 1 else 0.0 for c in cells]
    return max(float(np.sqrt(np.sum(np.square(stds)))), TIE_FLOOR)


def _seeds(cell) -> int:
    return int(cell.get("n", 1)) if isinstance(cell, dict) else 1


def _less(a, b) -> bool | str:
    """Cell a below cell b: True, False, or "tie" when the gap is within the seeds' noise."""
    gap = _m(b) - _m(a)
    return "tie" if abs(gap) <= _noise(a, b) else gap > 0


def _all_of(verdicts) -> bool | str:
    """Every verdict True: True; any False: False; else "tie" (some within the seeds' noise, none against)."""
    vs = list(verdicts)
    return False if False in vs else ("tie" if "tie" in vs else True)


def _listed(items: list) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


def _lowers_text(per_target: dict) -> str:
    """'yes', or where calibration did not lower the error beyond the noise: 'within noise on mini-2/gel-1'."""
    said = []
    for verdict, word in (("tie", "within noise"), (False, "raised")):
        targets = [t for t, v in per_target.items() if v == verdict]
        if targets:
            said.append(f"{word} on {_listed(targets)}")
    return "; ".join(said) or "yes"


def findings(results: dict) -> dict:
    """One plain sentence per table: does the paper's finding (ordering, gaps) show in our numbers? Gaps within
    the seeds' spread (or below the tables' resolution with one seed) are reported as ties. A run whose preset
    judges nothing (common.verdicts: smoke) keeps the rankings, without a verdict, and "note" says so once."""
    t1, t2, t3 = results["table1"], results["table2"], results["table3"]
    judge = common.verdicts(results)
    out = {}

    def order(table):
        return sorted(table, key=lambda m: _m(table[m]["mean"]))

    def says(claim: str, holds, detail: str) -> str:
        verdict = {None: "not measured", "tie": "tie, not resolved (within seed noise)", True: "reproduces",
                   False: "does NOT reproduce"}[holds]
        return f"{claim}: {verdict} ({detail})." if judge else ""

    def joined(sentences) -> str:
        return " ".join(x for x in sentences if x)

    def extreme(table, method, ranked) -> bool | str:
        """Is `method` last in `ranked`? "tie" when it and its nearest rival there are within noise (e.g.
        two bitwise identical variants)."""
        end = ranked[-1]
        rival = end if end != method else (ranked[-2] if len(ranked) > 1 else None)
        if rival is not None and _less(table[rival]["mean"], table[method]["mean"]) == "tie":
            return "tie"
        return end == method

    def ends(table, ranked, word) -> str:
        return ", ".join(f"{w}: {_name(m)} {_m(table[m]['mean']):.1f}%"
                         for w, m in zip((f"{word} here", "next"), ranked[:2]))

    def has(table, *ms):
        return all(m in table for m in ms)

    rank1 = order(t1)
    ranked = ", ".join(f"{_name(m)} {_m(t1[m]['mean']):.1f}%" for m in rank1)
    s = [f"Table I ranking here (best first): {ranked}; "
         f"paper: DINO RD 4.2%, DINO R 5.2%, ResNet RD 5.3%, DINO_F RD 8.5%."]
    if has(t1, "dino_rd", "dino_r"):
        d, r = _m(t1["dino_rd"]["mean"]), _m(t1["dino_r"]["mean"])
        s.append(says("Depth decoder helps on unseen objects (DINO RD < DINO R)",
                      _less(t1["dino_rd"]["mean"], t1["dino_r"]["mean"]), f"{d:.1f}% vs {r:.1f}%"))
    if has(t1, "dino_f_rd", "dino_rd"):
        f, d = _m(t1["dino_f_rd"]["mean"]), _m(t1["dino_rd"]["mean"])
        s.append(says("Fine-tuning beats a frozen backbone (DINO RD < DINO_F RD)",
                      _less(t1["dino_rd"]["mean"], t1["dino_f_rd"]["mean"]), f"{d:.1f}% vs {f:.1f}%"))
    if has(t1, "dino_rd", "resnet_rd"):
        d, r = _m(t1["dino_rd"]["mean"]), _m(t1["resnet_rd"]["mean"])
        s.append(says("ViT beats ResNet (DINO RD < ResNet RD)", _less(t1["dino_rd"]["mean"], t1["resnet_rd"]["mean"]),
                      f"{d:.1f}% vs {r:.1f}%"))
    if judge and all(_seeds(t1[m]["mean"]) < 2 for m in t1):
        s.append("One seed: these gaps are not tested against seed noise (ties are only gaps under 0.05 points).")
    out["table1"] = joined(s)

    rank2 = order(t2)
    ranked = ", ".join(f"{_name(m)} {_m(t2[m]['mean']):.1f}%" for m in rank2)
    s = [f"Table II mean over 9 GelSight units x gels (best first): {ranked}; "
         f"paper: DINO RD 5.4%, DINO R 5.8%, ResNet RD 6.0%, DINO_F R 8.8%."]
    if rank2:
        train_cell = {m: _m(t2[m]["mini-1/gel-1"]) for m in t2}
        other = {m: np.mean([_m(t2[m][P.sensor_label(k)]) for k in P.SENSORS[1:]]) for m in t2}
        grows = all(other[m] > train_cell[m] for m in t2)
        s.append(says("Error grows away from the training sensor/gel (all methods)", grows,
                      "; ".join(f"{_name(m)} {train_cell[m]:.1f}% -> {other[m]:.1f}%" for m in t2)))
    if has(t2, "dino_f_r"):
        s.append(says("The frozen backbone (DINO_F R) is worst", extreme(t2, "dino_f_r", rank2),
                      ends(t2, rank2[::-1], "worst")))
    if has(t2, "dino_rd"):
        s.append(says("DINO RD has the lowest mean", extreme(t2, "dino_rd", rank2[::-1]),
                      ends(t2, rank2, "lowest")))
    out["table2"] = joined(s)

    s = []
    if t3:
        # per target: True lowered, False raised, "tie" moved within the seeds' noise
        lowers = {m: {t: _less(c["after"], c["before"]) for t, c in t3[m].items()} for m in t3}
        n_cal = results["config"]["data"]["calib_samples"]
        s.append(says(f"Calibration with {n_cal} Big Sphere presses lowers the target sensor's error",
                      _all_of(v for per in lowers.values() for v in per.values()),
                      "; ".join(f"{_name(m)}: {_lowers_text(per)}" for m, per in lowers.items())))
        if all("digit" in t3[m] for m in t3):
            digit = {m: {"mean": t3[m]["digit"]["after"]} for m in t3}
            ranked = sorted(digit, key=lambda m: -_m(digit[m]["mean"]))  # worst first: extreme() asks who is last
            best = ranked[-1]
            s.append(says("DINO RD is best on DIGIT after calibration",
                          extreme(digit, "dino_rd", ranked) if "dino_rd" in t3 else None,
                          f"best here: {_name(best)} {_m(t3[best]['digit']['after']):.1f}%"
                          + "".join(f", {_name(m)} {_m(t3[m]['digit']['after']):.1f}%" for m in ranked[-2::-1])))
        deg = {m: np.mean([_m(c["degradation_pct"]) for k, c in t3[m].items() if k != "digit"]) for m in t3}
        least = min(deg, key=deg.get)
        s.append(says("DINO RD's uncalibrated sensors degrade least after a GelSight calibration (paper 4% vs "
                      "12-25%)", least == "dino_rd" if "dino_rd" in deg else None,
                      ", ".join(f"{_name(m)} {v:+.1f}%" for m, v in deg.items())))
    out["table3"] = joined(s)
    if not judge:
        out["note"] = common.no_verdict(results)
    return out


def _paper(table: dict, method: str, i: int) -> str:
    v = table.get(method)
    return f"{v[i]:.1f}" if v else "–"


def table1_md(results: dict) -> tuple[str, list, list]:
    t1 = results["table1"]
    objs = [o for o in P.OBJECTS if any(o in t1[m] for m in t1)]
    labels = [P.OBJECT_LABELS[P.OBJECTS.index(o)] for o in objs]
    header = ["Method"] + labels + ["Mean", "Paper mean"]
    rows, csv_rows = [], []
    for m in t1:
        rows.append([_name(m)] + [common.fmt(t1[m].get(o)) for o in objs] + [common.fmt(t1[m]["mean"]),
                                                                              _paper(P.TABLE1, m, 10)])
        csv_rows.append([m] + [_m(t1[m].get(o)) for o in objs] + [_m(t1[m]["mean"])])
    paper_rows = [[f"paper: {_name(m)}"] + [f"{v:.1f}" for v in P.TABLE1[m][:10]] + [f"{P.TABLE1[m][10]:.1f}", ""]
                  for m in P.TABLE1]
    text = (f"# Table I: unseen objects (normalized L1 %, mean ± std over {len(results['seeds'])} seed(s))\n\n"
            + common.md_table(header, rows) + "\nThe paper's numbers (real GelSight Mini data):\n\n"
            + common.md_table(header, paper_rows) + "\n" + results["findings"]["table1"] + "\n")
    return text, ["method"] + list(objs) + ["mean"], csv_rows


def table2_md(results: dict) -> tuple[str, list, list]:
    t2 = results["table2"]
    keys = [P.sensor_label(s) for s in P.SENSORS]
    extra = ["digit"] if any("digit" in t2[m] for m in t2) else []
    header = ["Method"] + [k.replace("mini-", "S").replace("/gel-", " G") for k in keys] + ["Mean", "Paper mean"]
    header += ["DIGIT (not in paper's Table II)"] * bool(extra)
    rows, csv_rows = [], []
    for m in t2:
        rows.append([_name(m)] + [common.fmt(t2[m].get(k)) for k in keys] + [common.fmt(t2[m]["mean"]),
                                                                             _paper(P.TABLE2, m, 9)]
                    + [common.fmt(t2[m].get(k)) for k in extra])
        csv_rows.append([m] + [_m(t2[m].get(k)) for k in keys + extra] + [_m(t2[m]["mean"])])
    paper_rows = [[f"paper: {_name(m)}"] + [f"{v:.1f}" for v in P.TABLE2[m][:9]] + [f"{P.TABLE2[m][9]:.1f}", ""]
                  + [""] * bool(extra) for m in P.TABLE2]
    text = (f"# Table II: trained on mini-1 gel 1, tested on every unit x gel (normalized L1 %, "
            f"{len(results['seeds'])} seed(s))\n\nS = GelSight Mini unit, G = gel.\n\n"
            + common.md_table(header, rows) + "\nThe paper's numbers:\n\n" + common.md_table(header, paper_rows)
            + "\n" + results["findings"]["table2"] + "\n")
    return text, ["method"] + keys + extra + ["mean"], csv_rows


def table3_md(results: dict) -> tuple[str, list, list]:
    t3 = results["table3"]
    targets = [P.sensor_label(t) for t in P.CALIB_TARGETS]
    header = ["Target (layers tuned)"] + [f"{_name(m)} before → after" for m in t3] + \
             [f"paper {_name(m)}" for m in t3 if m in P.TABLE3]
    rows, csv_rows = [], []
    for i, t in enumerate(targets):
        layers = next((t3[m][t]["layers"] for m in t3 if t in t3[m]), "")
        rows.append([f"{t} ({layers})"]
                    + [_before_after(t3[m][t]) if t in t3[m] else "–"
                       for m in t3]
                    + [f"{P.TABLE3[m][i]:.1f}" for m in t3 if m in P.TABLE3])
        csv_rows += [[m, t, t3[m][t]["layers"], _m(t3[m][t]["before"]), _m(t3[m][t]["after"]),
                      _m(t3[m][t]["others_before"]), _m(t3[m][t]["others_after"]), _m(t3[m][t]["degradation_pct"])]
                     for m in t3 if t in t3[m]]
    deg_header = ["Calibrated on"] + [_name(m) for m in t3]
    deg_rows = [[t] + [f"{common.fmt(t3[m][t]['others_before'])} → {common.fmt(t3[m][t]['others_after'])} "
                       f"({common.fmt(t3[m][t]['degradation_pct'])}%)" if t in t3[m] else "–" for m in t3]
                for t in targets]
    text = (f"# Table III: calibration with {results['config']['data']['calib_samples']} Big Sphere presses "
            f"(normalized L1 % on the target's Table II test set; {len(results['seeds'])} seed(s))\n\n"
            + common.md_table(header, rows)
            + "\nThe other (uncalibrated) GelSight units after each calibration: mean error before → after "
              "(relative change). Paper: +4% for DINO RD vs +12-25% for the others.\n\n"
            + common.md_table(deg_header, deg_rows) + "\n" + results["findings"]["table3"] + "\n")
    return text, ["method", "target", "layers", "before", "after", "others_before", "others_after",
                  "degradation_pct"], csv_rows


@style.plots
def plot_all(results: dict, out: Path) -> list[Path]:
    """table{1,2,3}.png: per method our bar (filled, its colour) with the paper's value beside it (hollow, hatched,
    the same colour: style.paper_bars), never on it; error bars only over >= 2 seeds; a paper value far above our
    bars is clipped at the top with its number written there; legends outside the data; preset, seeds and commit
    stamped on each figure."""
    paths = []
    methods = list(results["table1"])
    multi_seed = len(results.get("seeds", [])) >= 2
    hatches = _hatches(results["table1"])
    seeds_txt = f"mean ± std over {len(results['seeds'])} seeds" if multi_seed else "1 seed, no error bars"

    def key(ax, paper_drawn: bool, clipped: int = 0):
        from matplotlib.patches import Patch

        handles = [Patch(facecolor=style.colour(m), hatch=hatches[m][0], edgecolor="white" if hatches[m][0] else None,
                         label=_name(m) + (f" (= {hatches[m][1]})" if hatches[m][1] else "")) for m in methods]
        bars_said = style.bar_key(seeds_txt)
        handles += [bars_said[0]] + ([bars_said[1]] if paper_drawn else []) + (style.clipped_key() if clipped else [])
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)

    def finish(fig, path):
        common.stamp(fig, results["preset"], results.get("seeds", []), results.get("commit", "?"))
        paths.append(style.save(fig, path))

    def bars(ax, groups, getter, paper: dict, index) -> tuple[bool, int]:
        """Each method's bars over the groups; paper: its values by group index (`index(group)`). Returns whether
        any paper value was drawn, and how many were clipped at the axis' top."""
        slot = 0.84 / len(methods)
        ours_w, paper_w = 0.56 * slot, 0.38 * slot
        x = np.arange(len(groups))
        vals = {m: [getter(m, g) for g in groups] for m in methods}
        high = max((_m(v) + (v["std"] if multi_seed else 0) for vs in vals.values() for v in vs
                    if v and np.isfinite(_m(v))), default=1.0)
        cols = {m: [index(g) for g in groups] for m in methods if m in paper}
        theirs = {m: [paper[m][i] if i is not None and i < len(paper[m]) else np.nan for i in cols[m]] for m in cols}
        top = style.paper_top(high, [v for vs in theirs.values() for v in vs])
        clipped = 0
        for i, m in enumerate(methods):
            left = x - 0.42 + i * slot
            err = [v["std"] if v else 0 for v in vals[m]] if multi_seed else None
            ax.bar(left + ours_w / 2, [_m(v) for v in vals[m]], ours_w, yerr=err, capsize=1.5 if multi_seed else 0,
                   color=style.colour(m), hatch=hatches[m][0], edgecolor="white" if hatches[m][0] else None,
                   error_kw={"lw": 0.9, "zorder": 4}, zorder=3)
            if m in theirs:
                clipped += style.paper_bars(ax, left + ours_w + paper_w / 2, theirs[m], paper_w, m, top)
        ax.set_ylim(0, top)
        ax.set_xticks(x)
        ax.set_xlim(-0.55, len(groups) - 0.45)
        style.error_axis(ax)
        ax.grid(axis="y")
        return bool(theirs), clipped

    t1 = results["table1"]
    objs = [o for o in P.OBJECTS if o in t1[methods[0]]] + ["mean"]
    fig, ax = style.figure(figsize=(13, 4.4))
    # the paper's row holds its objects in P.OBJECTS' order, then the mean: matched by name, not by position
    drawn = bars(ax, objs, lambda m, g: t1[m].get(g), P.TABLE1,
                 lambda g: len(P.OBJECTS) if g == "mean" else P.OBJECTS.index(g))
    ax.set_xticklabels([o.replace("_", " ") for o in objs], rotation=30, ha="right")
    ax.set_title(f"Table I: unseen objects, trained on mini-1/gel-1 ({seeds_txt})")
    key(ax, *drawn)
    finish(fig, out / "table1.png")

    t2 = results["table2"]
    keys = [P.sensor_label(s) for s in P.SENSORS] + ["mean"]
    fig, ax = style.figure(figsize=(13, 4.4))
    drawn = bars(ax, keys, lambda m, g: t2[m].get(g), P.TABLE2, lambda g: keys.index(g))
    ax.set_xticklabels(keys, rotation=30, ha="right")
    ax.set_title(f"Table II: every GelSight unit x gel, trained on mini-1/gel-1 ({seeds_txt})")
    key(ax, *drawn)
    finish(fig, out / "table2.png")

    t3 = results["table3"]
    targets = [P.sensor_label(t) for t in P.CALIB_TARGETS]
    fig, axes = style.figure(1, len(targets), figsize=(13.5, 4.0), squeeze=False)
    axes = axes[0]
    drawn, clipped = False, 0
    for j, (ax, t) in enumerate(zip(axes, targets)):
        x = np.arange(len(methods))
        w = 0.28
        high = 1.0
        for i, m in enumerate(methods):
            c = style.colour(m)
            for dx, when, alpha in ((-w, "before", 0.35), (0.0, "after", 1.0)):
                if t not in t3[m]:
                    continue
                cell = t3[m][t][when]
                err = cell["std"] if multi_seed else None
                ax.bar(i + dx, _m(cell), w, yerr=err, color=c, alpha=alpha, capsize=1.5 if multi_seed else 0,
                       error_kw={"lw": 0.9, "zorder": 4}, zorder=3)
                high = max(high, _m(cell) + (err or 0))
        paper = {m: P.TABLE3[m][j] for m in methods if m in P.TABLE3}  # P.TABLE3: in CALIB_TARGETS' order
        top = style.paper_top(high, paper.values())
        for i, m in enumerate(methods):
            if m in paper:
                clipped += style.paper_bars(ax, [i + w], [paper[m]], w, m, top)
                drawn = True
        ax.set_ylim(0, top)
        ax.set_xticks(x)
        ax.set_xticklabels([_name(m) for m in methods], rotation=30, ha="right")
        ax.set_xlim(-0.6, len(methods) - 0.4)
        ax.grid(axis="y")
        layers = next((t3[m][t]["layers"] for m in methods if t in t3[m]), "")
        ax.set_title(f"{t} (layers tuned: {layers})")
    style.error_axis(axes[0])
    fig.suptitle(f"Table III: calibration with {results['config']['data']['calib_samples']} Big Sphere presses "
                 f"({seeds_txt})")
    from matplotlib.patches import Patch

    ours, theirs = style.bar_key(seeds_txt)
    ours.set_label(f"{style.OURS_LABEL}, after calibration: {seeds_txt}")
    theirs.set_label(f"{style.PAPER_LABEL}, after calibration")
    before = Patch(facecolor="0.45", alpha=0.35, label=f"{style.OURS_LABEL}, before calibration (pale)")
    axes[-1].legend(handles=[*style.method_key(methods), before, ours] + ([theirs] if drawn else [])
                    + (style.clipped_key() if clipped else []),
                    loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
    finish(fig, out / "table3.png")
    return paths


def _before_after(cell: dict) -> str:
    """'8.1 → **6.8**': the after-calibration number in bold only where calibration lowered the error beyond the
    seeds' noise."""
    before, after = common.fmt(cell["before"]), common.fmt(cell["after"])
    return f"{before} → **{after}**" if _less(cell["after"], cell["before"]) is True else f"{before} → {after}"


def _hatches(t1: dict) -> dict:
    """Methods whose Table I cells equal an earlier method's (e.g. DINO_F R and DINO_F RD, whose regressor
    sees the same frozen features) get a hatch and '(= other)' in the legend, instead of hiding behind it."""
    out, seen = {}, {}
    for m, cells in t1.items():
        key = json.dumps({k: _m(v) for k, v in cells.items()}, sort_keys=True)
        out[m] = ("..", _name(seen[key])) if key in seen else (None, "")
        seen.setdefault(key, m)
    return out


def save_png(fig, path: Path, then=None, bottom: float = 0.0) -> Path:
    """style.save (kept under this name for the diagnostics that import it from here)."""
    return style.save(fig, path, then=then, bottom=bottom)


def seed_span(seeds) -> str:
    """Seeds as people write them: [0, 1, 2] -> '0-2', [0] -> '0', [0, 1, 4] -> '0-1, 4'."""
    spans: list[list[int]] = []
    for k in sorted({int(k) for k in seeds}):
        if spans and k == spans[-1][1] + 1:
            spans[-1][1] = k
        else:
            spans.append([k, k])
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in spans)


REUSE_WORDS = {False: "{here}", None: "the cells partly reused from the ablation",
               True: "the cells reused from the ablation"}  # by where a cell's runs came from: none, some, all


def seed_groups(cells: dict) -> list[tuple[str, list, list[str]]]:
    """Cells {label: (seeds, reused)} grouped by their seeds: [(seed span, the groups' `reused` values in
    REUSE_WORDS' order, labels)], fewest seeds first. reused: True = every run of the cell the ablation's, False =
    none, None = some."""
    groups: dict = {}
    for label, (seeds, reused) in cells.items():
        groups.setdefault((len(set(seeds)), seed_span(seeds)), []).append((label, reused))
    return [(span, [r for r in REUSE_WORDS if r in {x for _, x in members}], [lab for lab, _ in members])
            for (_, span), members in sorted(groups.items())]


def seeds_text(cells: dict, here: str = "the cells trained here", names=None) -> str:
    """What seeds a figure or table holds, in words, from its cells {label: (seeds, reused)}: '0-2' when every cell
    has the same seeds, else per group, e.g. "0 for the sweep's own cells; 0-2 for the cells reused from the
    ablation". names: a function of a group's labels whose text follows the group in brackets (None: no names)."""
    groups = seed_groups(cells)
    if len(groups) <= 1:
        return groups[0][0] if groups else "none"
    return "; ".join(f"{span} for {' and '.join(REUSE_WORDS[r].format(here=here) for r in reused)}"
                     + (f" ({names(labels)})" if names else "") for span, reused, labels in groups)


def write_all(results: dict, out: Path) -> None:
    out = Path(out)
    for name, fn in (("table1", table1_md), ("table2", table2_md), ("table3", table3_md)):
        text, header, rows = fn(results)
        common.write_text(out / f"{name}.md", text)
        common.write_csv(out / f"{name}.csv", header, rows)
    plot_all(results, out)
    common.write_json(out / "results.json", results)


def console_summary(results: dict) -> str:
    lines = [f"preset {results['preset']}, seeds {results['seeds']}, commit {results['commit'][:12]}"]
    for m in results["table1"]:
        t3 = results["table3"][m]
        cal = ", ".join(f"{t} {_m(c['after']):.1f}%" for t, c in t3.items())
        lines.append(f"  {_name(m):10s} Table I {_m(results['table1'][m]['mean']):5.1f}%   "
                     f"Table II {_m(results['table2'][m]['mean']):5.1f}%   Table III {cal}")
    lines += ["", *(text for text in results["findings"].values() if text)]
    return "\n".join(lines)
