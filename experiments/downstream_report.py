"""Tables (markdown laid out like the paper's, CSV) and plots of the downstream results (experiments.downstream):
drawn from its results.json only, so `python -m experiments.replot` redraws all of them."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from experiments import common, style, tables
from ffjax.tasks import grasping, pushing

PERFECT = "perfect"
ROWS = (
    ("force_est", "Force GelSight (ours) [N]", 2),
    ("force_ref", "Force reference (ATI, drifting) [N]", 2),
    ("force_error", "Force error [N]", 2),
    ("weight_error", "Weight error [kg]", 2),
)
EXTRA = (
    ("force_true", "True push force [N]", 2),
    ("mu_true", "mu true (object-table)", 3),
    ("mu_fit", "mu fitted from the reference", 3),
    ("mass_est", "Estimated mass [kg]", 3),
    ("weight_error_true_mu", "Weight error with the true mu [kg]", 2),
)


def _name(method: str) -> str:
    """The name people read; the true force as the estimate is "perfect sensor"."""
    return "perfect sensor" if method == PERFECT else style.name(method)


def _v(ms) -> float:
    return ms["mean"] if isinstance(ms, dict) else float(ms)


def _seed(run) -> int | None:
    """The training seed a checkpoint's folder names (.../dino_rd/seed0), None where it names none."""
    m = re.search(r"seed(\d+)$", str(run).rstrip("/"))
    return int(m.group(1)) if m else None


def first_checkpoint(res: dict, method: str) -> str:
    """Which checkpoint a one-checkpoint figure shows (the method's first, as experiments.downstream uses), in
    words: 'one DINO RD checkpoint (seed 0)', or its folder's name where that names no seed."""
    runs = res.get("checkpoints", {}).get(method) or []
    if not runs:
        return f"one {_name(method)} checkpoint"
    seed = _seed(runs[0])
    return f"one {_name(method)} checkpoint ({f'seed {seed}' if seed is not None else Path(runs[0]).name})"


def _over_seeds(res: dict, methods) -> str:
    """What the figure's means are over: 'mean ± std over seeds 0-2' where every method's checkpoints have those
    seeds, 'seed 0, no spread' for one seed each."""
    spans = set()
    for m in methods:
        seeds = [_seed(r) for r in res.get("checkpoints", {}).get(m, [])]
        spans.add(tables.seed_span(seeds) if seeds and None not in seeds else None)
    if len(spans) != 1 or None in spans:
        return "mean ± std over each method's checkpoints"
    span = spans.pop()
    return f"seed {span}, no spread" if span.isdigit() else f"mean ± std over seeds {span}"


def stamp(fig, res: dict, runs=None) -> None:
    """The figure's provenance in its corner (preset, the training seeds of its checkpoints: `runs`, default every
    checkpoint; commit): see ffjax.results.stamp."""
    if runs is None:
        runs = [r for rs in res.get("checkpoints", {}).values() for r in rs]
    seeds = [s for s in map(_seed, runs) if s is not None]
    common.stamp(fig, res.get("preset", "?"), [], res.get("commit", "?"),
                 seeds_text=tables.seed_span(seeds) if seeds else "?")


def table4_md(res: dict) -> str:
    push = res["pushing"]
    m = res["main_method"]
    objs = pushing.OBJECTS
    head = ["weight [kg]", *[o.label for o in objs]]
    tab = push["table"][m]
    rows = [[label, *[f"{common.fmt(tab[o.name][k], d)} ({o.paper[k]:g})" for o in objs]] for k, label, d in ROWS]
    extra = [[label, *[common.fmt(tab[o.name][k], d) for o in objs]] for k, label, d in EXTRA]
    perf = push["table"][PERFECT]
    extra.append(
        ["Weight error, perfect tactile sensor [kg]", *[common.fmt(perf[o.name]["weight_error"], 3) for o in objs]]
    )
    out = [
        f"# Table IV: weighing by pushing ({res['preset']} preset, {_name(m)}; the paper's values in brackets)\n",
        f"{res['push_config']['pushes']} pushes of {push['duration_s']:g} s per object at "
        f"{res['push_config']['fps']:g} fps (camera 25 fps), averaged over the constant-velocity phase; "
        "mu fitted from the reference sensor with the known mass (mu = f_ref / m g), "
        "weight = f_est / (mu g).\n",
        common.md_table(head, rows),
        "\nDiagnostics (not in the paper):\n",
        common.md_table(head, extra),
    ]
    # every method
    methods = [k for k in push["table"] if k != PERFECT] + [PERFECT]
    mrows = []
    for meth in methods:
        t = push["table"][meth]
        mrows.append(
            [
                _name(meth),
                *[
                    f"{common.fmt(t[o.name]['force_error'], 2)} / {common.fmt(t[o.name]['weight_error'], 3)}"
                    for o in objs
                ],
                common.fmt(_pct(t["mean"]["weight_error_rel"]), 1),
            ]
        )
    out += [
        "\n## Every method: force error [N] / weight error [kg]\n",
        "(perfect sensor = the tactile estimate is the true force: what remains is the drifting reference "
        "and the table.)\n",
        common.md_table(["method", *[o.label for o in objs], "mean weight error %"], mrows),
    ]
    # duration sweep
    durs = push["durations"]
    drows = [
        [_name(meth), *[common.fmt(_pct(push["sweep"][meth][str(T)]["mean"]["weight_error_rel"]), 1) for T in durs]]
        for meth in methods
    ]
    out += [
        "\n## Push duration: mean weight error % over the four objects\n",
        common.md_table(["method", *[f"{T:g} s" for T in durs]], drows),
    ]
    return "".join(out)


def _pct(ms: dict) -> dict:
    return {**ms, "mean": 100 * ms["mean"], "std": 100 * ms["std"]}


def grasping_md(res: dict) -> str:
    g = res["grasping"]["summary"]
    m = res["main_method"]
    cup = res["cup"]
    out = [
        f"# Grasping to a target force ({res['preset']} preset, {_name(m)})\n\n",
        f"Plastic cup rim: k = {cup['stiffness_n_per_mm']:.3f} N/mm "
        "(thin-ring model, see ffjax/tasks/grasping.py), "
        f"diameter {cup['diameter_mm']:g} mm; gripper step {res['gripper']['step_mm']:g} mm; "
        f"{len(res['grasping']['cup'][PERFECT][0][str(cup['targets'][0])])} trials with small pose changes. "
        "The gripper closes until the reading of either sensor reaches the target.\n\n",
    ]
    rows = []
    for T in cup["targets"]:
        t, e = g["cup"][PERFECT][str(T)], g["cup"][m][str(T)]
        p = cup["paper"][str(T)] if str(T) in cup["paper"] else cup["paper"][T]
        rows.append(
            [
                f"{T:g}",
                f"{common.fmt(t['deformation_pct'], 2)} ({p['true']})",
                f"{common.fmt(e['deformation_pct'], 2)} ({p['est']})",
                common.fmt(e["abs_deformation_error_pct"], 2),
                common.fmt(t["overshoot_n"], 3),
                common.fmt(t["step_increment_n"], 3),
                common.fmt(e["overshoot_n"], 2),
                f"{100 * e['reached']:.0f}%",
            ]
        )
    out.append(
        common.md_table(
            [
                "target [N]",
                "deformation % true force (paper)",
                "deformation % estimated (paper)",
                "abs deformation error %",
                "overshoot, true force [N]",
                "one step [N]",
                "true force - target, estimated control [N]",
                "target reached",
            ],
            rows,
        )
    )
    out.append("\n## Fruits: success rate (final true force between the gentle and firm thresholds)\n\n")
    frows = []
    for f in grasping.FRUITS:
        t, e = g["fruits"][PERFECT][f.name], g["fruits"][m][f.name]
        frows.append(
            [
                f.name,
                f"{f.gentle_n:.2f}",
                f"{f.firm_n:.2f}",
                f"{100 * t['gentle']['success']:.0f}% / {100 * e['gentle']['success']:.0f}%",
                f"{100 * t['firm']['success']:.0f}% / {100 * e['firm']['success']:.0f}%",
                common.fmt(e["gentle"]["force"], 2),
                common.fmt(e["firm"]["force"], 2),
            ]
        )
    out.append(
        common.md_table(
            [
                "fruit",
                "gentle [N]",
                "firm [N]",
                "gentle success true / est.",
                "firm success true / est.",
                "final force gentle, est. [N]",
                "final force firm, est. [N]",
            ],
            frows,
        )
    )
    out.append("\n## Every method\n\n")
    mrows = []
    for meth in [k for k in g["cup"] if k != PERFECT]:
        cu = g["cup"][meth]
        fr = g["fruits"][meth]
        succ = np.mean([fr[f][mode]["success"] for f in fr for mode in fr[f]])
        mrows.append(
            [
                _name(meth),
                *[common.fmt(cu[str(T)]["abs_deformation_error_pct"], 2) for T in cup["targets"]],
                *[common.fmt(cu[str(T)]["overshoot_n"], 2) for T in cup["targets"]],
                f"{100 * succ:.0f}%",
            ]
        )
    out.append(
        common.md_table(
            [
                "method",
                *[f"abs def. error % @{T:g} N" for T in cup["targets"]],
                *[f"force - target @{T:g} N" for T in cup["targets"]],
                "fruit grasp success",
            ],
            mrows,
        )
    )
    return "".join(out)


def write_csvs(res: dict, out: Path) -> None:
    push = res["pushing"]
    fields = [
        "force_est",
        "force_ref",
        "force_true",
        "force_error",
        "mu_true",
        "mu_fit",
        "mass_est",
        "weight_error",
        "weight_error_true_mu",
    ]
    rows = [
        [m, o.name, o.mass_kg, *[_v(push["table"][m][o.name][f]) for f in fields]]
        for m in push["table"]
        for o in pushing.OBJECTS
    ]
    common.write_csv(out / "table4.csv", ["method", "object", "mass", *fields], rows)
    rows = [
        [
            m,
            T,
            o.name,
            _v(push["sweep"][m][str(T)][o.name]["weight_error"]),
            _v(push["sweep"][m][str(T)][o.name]["force_error"]),
        ]
        for m in push["sweep"]
        for T in push["durations"]
        for o in pushing.OBJECTS
    ]
    common.write_csv(
        out / "push_duration.csv", ["method", "duration_s", "object", "weight_error", "force_error"], rows
    )
    g = res["grasping"]
    rows = [
        [
            m,
            i,
            T,
            k,
            r["stop_step"],
            r["force"],
            r["deformation_pct"],
            r["overshoot_n"],
            r["step_increment_n"],
            r["reached"],
        ]
        for m, ck in g["cup"].items()
        for i, c_ in enumerate(ck)
        for T, rs in c_.items()
        for k, r in enumerate(rs)
    ]
    common.write_csv(
        out / "grasp_cup.csv",
        [
            "method",
            "checkpoint",
            "target",
            "trial",
            "stop_step",
            "force",
            "deformation_pct",
            "overshoot_n",
            "step_increment_n",
            "reached",
        ],
        rows,
    )
    rows = [
        [m, i, f, mode, k, r["stop_step"], r["force"], r["success"]]
        for m, ck in g["fruits"].items()
        for i, c_ in enumerate(ck)
        for f, modes in c_.items()
        for mode, rs in modes.items()
        for k, r in enumerate(rs)
    ]
    common.write_csv(
        out / "grasp_fruits.csv",
        ["method", "checkpoint", "fruit", "mode", "trial", "stop_step", "force", "success"],
        rows,
    )


@style.plots
def plots(res: dict, out: Path, push_trace: dict | None) -> list[str]:
    """push_force.png (one push, where a trace was kept), push_duration.png and grasp_steps.png (where a cup trace
    was kept); matplotlib is loaded only here (slow to import), not by the tasks themselves."""
    made = []
    if push_trace is not None:
        tr = push_trace
        fig, ax = style.figure(figsize=(9, 3.6), layout="constrained")
        const = np.asarray(tr["phase"]) == 2
        if const.any():
            ax.axvspan(
                np.asarray(tr["t"])[const][0],
                np.asarray(tr["t"])[-1],
                color="0.92",
                label="constant velocity",
            )
        ax.plot(tr["t"], tr["true"], "k-", lw=1.2, label="true push force")
        ax.plot(tr["t"], tr["reference"], "-", color="0.55", lw=0.8, label="reference sensor (drifting)")
        ax.plot(tr["t"], tr["estimate"], ".-", color=style.colour(tr["method"]), lw=0.8, ms=3,
                label=f"estimate ({_name(tr['method'])})")
        t_end, window = float(np.asarray(tr["t"])[-1]), float(res["pushing"]["duration_s"])
        if window < t_end:  # the sweep's longest push is simulated; Table IV reads its first `window` seconds
            ax.axvline(window, color="0.4", ls=":", lw=1, label=f"Table IV window ends ({window:g} s)")
        ax.set(
            xlabel="time [s]",
            ylabel="Fz = push force [N]",
            title=f"One push of {tr['object']} ({t_end + float(np.diff(tr['t'][:2])[0]):.0f} s simulated), "
                  f"{first_checkpoint(res, tr['method'])}",
        )
        fig.legend(loc="outside right center")
        stamp(fig, res, res.get("checkpoints", {}).get(tr["method"], [])[:1])
        style.save(fig, out / "push_force.png")
        made.append("push_force.png")
    push = res["pushing"]
    fig, ax = style.figure(figsize=(9, 3.8), layout="constrained")
    seen: dict = {}
    durations = np.asarray(push["durations"], float)
    methods = [m for m in push["sweep"] if m != PERFECT]
    for m in push["sweep"]:
        cells = [push["sweep"][m][str(T)]["mean"]["weight_error_rel"] for T in push["durations"]]
        y = [100 * c["mean"] for c in cells]
        if m == PERFECT:
            ax.plot(durations, y, "k:", label="perfect sensor (the true force as the estimate)")
            continue
        key = tuple(round(v, 6) for v in y)  # equal curves (DINO_F R, DINO_F RD) are dashed, hollow, and say so
        twin = seen.setdefault(key, m)
        n = max(c.get("n", 1) for c in cells)
        label = _name(m) + (f" (= {_name(twin)})" if twin != m else "") + (f", {n} seeds" if n > 1 else ", 1 seed")
        # side by side at each duration, so the error bars (± std over the checkpoints' seeds) do not overlap
        shift = durations * 0.025 * (methods.index(m) - (len(methods) - 1) / 2)
        ax.errorbar(durations + shift, y, yerr=[100 * c.get("std", 0.0) for c in cells] if n > 1 else None,
                    color=style.colour(m), marker=style.marker(m), ls="--" if twin != m else "-", capsize=2.5,
                    mfc="white" if twin != m else style.colour(m), label=label)
    ax.set(xlabel="push duration [s]", ylabel="mean weight error, four objects [%]")
    ax.grid(alpha=0.3)
    fig.suptitle(f"Weighing error against push duration ({res.get('preset', '?')} models; {_over_seeds(res, methods)})")
    fig.legend(loc="outside right center")
    stamp(fig, res)
    style.save(fig, out / "push_duration.png")
    made.append("push_duration.png")
    tr = res["grasping"].get("cup_trace")
    if tr:
        fig, (a1, a2) = style.figure(2, 1, figsize=(8.5, 5), sharex=True, layout="constrained")
        a1.plot(tr["steps"], tr["true"], "k.-", label="true force")
        names = [f"{n}-gel{g}" for n, g in res["gripper"]["sensors"]]
        colour = style.colour(res["main_method"])
        a1.plot(tr["steps"], tr["est_a"], "o-", color=colour, ms=3, label=f"estimate, jaw A ({names[0]})")
        a1.plot(tr["steps"], tr["est_b"], "s--", color=colour, ms=3, mfc="white",
                label=f"estimate, jaw B ({names[1]})")
        a1.axhline(tr["target"], color="0.3", ls="-.", lw=0.9, label="target")
        a1.axvline(tr["stop_true"], color="k", ls=":", lw=0.8, label="stop, control by the true force")
        a1.axvline(tr["stop_est"], color=colour, ls=":", lw=0.8, label="stop, control by the estimate")
        a1.set(ylabel="Fz [N]")
        fig.suptitle(f"Closing on the cup rim, {first_checkpoint(res, res['main_method'])}")
        fig.legend(loc="outside right center")
        a2.plot(tr["steps"], tr["deformation_pct"], "k.-")
        a2.set(xlabel="gripper step", ylabel="deformation [%]")
        stamp(fig, res, res.get("checkpoints", {}).get(res["main_method"], [])[:1])
        style.save(fig, out / "grasp_steps.png")
        made.append("grasp_steps.png")
    return made


def draw(res: dict, out) -> list[str]:
    """Every table, CSV and figure from a results.json's content (`python -m experiments.replot` too); returns
    the figures' names."""
    out = Path(out)
    common.write_text(out / "table4.md", table4_md(res))
    common.write_text(out / "grasping.md", grasping_md(res))
    write_csvs(res, out)
    return plots(res, out, res.get("push_trace"))


def write_all(res: dict, out, push_trace: dict | None = None) -> None:
    """results.json (with the push trace, so a replot can redraw push_force.png), then everything draw writes."""
    out = Path(out)
    if push_trace is not None:
        res["push_trace"] = {k: np.asarray(v).tolist() if isinstance(v, (list, np.ndarray)) else v
                             for k, v in push_trace.items()}
    common.write_json(out / "results.json", res)
    res["plots"] = draw(res, out)
    common.write_json(out / "results.json", res)


def console_summary(res: dict) -> str:
    m = res["main_method"]
    t = res["pushing"]["table"][m]
    lines = [
        f"weighing by pushing ({_name(m)}): "
        + ", ".join(
            f"{o.label} f_est {t[o.name]['force_est']['mean']:.2f} N "
            f"vs ref {t[o.name]['force_ref']['mean']:.2f} N, "
            f"weight err {t[o.name]['weight_error']['mean']:.3f} kg"
            for o in pushing.OBJECTS
        )
    ]
    g = res["grasping"]["summary"]["cup"]
    for T in res["cup"]["targets"]:
        lines.append(
            f"cup @ {T:g} N: deformation "
            f"{g[PERFECT][str(T)]['deformation_pct']['mean']:.2f}% (true force) vs "
            f"{g[m][str(T)]['deformation_pct']['mean']:.2f}% (estimate)"
        )
    return "\n".join(lines)
