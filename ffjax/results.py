"""Writing results: markdown tables, mean ± std, atomic JSON / CSV / text files, a figure's provenance stamp.

Used by the experiments, through experiments.common.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from ffjax.files import atomic_write_text


def write_json(path, obj) -> None:
    """Write JSON atomically (tmp + fsync + rename): a kill never leaves a half-written results file."""
    write_text(path, json.dumps(obj, indent=1, default=_jsonable))


def write_text(path, text: str) -> None:
    """Write text atomically (its folder made if missing): the old file or the new one survives a kill or a
    full disk, never a part."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)


def write_csv(path, header: list[str], rows: list[list]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(header)
    w.writerows(rows)
    write_text(path, buf.getvalue())


def read_json(path):
    """The JSON in `path`, or None where there is no such file."""
    path = Path(path)
    return json.loads(path.read_text()) if path.is_file() else None


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (tuple, set)):
        return list(o)
    return str(o)


def mean_std(values) -> dict:
    """{"mean", "std" (ddof 1; 0 for one value), "n"} over the finite values (None and NaN left out)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], np.float64)
    if len(v) == 0:
        return {"mean": float("nan"), "std": float("nan"), "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0, "n": int(len(v))}


def fmt(ms: dict | None, digits: int = 1) -> str:
    """'4.2 ± 0.3' (or '4.2' for one seed) from a mean_std dict."""
    if not ms or not np.isfinite(ms.get("mean", float("nan"))):
        return "–"
    if ms.get("n", 1) > 1:
        return f"{ms['mean']:.{digits}f} ± {ms['std']:.{digits}f}"
    return f"{ms['mean']:.{digits}f}"


def md_table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out) + "\n"


def stamp(fig, preset: str, seeds, commit: str, seeds_text: str | None = None) -> None:
    """Print what a figure was made from in its corner (preset, seeds, commit), and say so when the preset's
    numbers mean nothing: a PNG copied into a notebook keeps its provenance. No seeds (a simulator-only check
    trains nothing): none shown. seeds_text: the seeds already in words (e.g. "0-2", or "0 for ...; 0-2 for ..."
    where cells differ), printed instead of the list `seeds`."""
    if seeds_text:
        said = f" · seed{'' if seeds_text.isdigit() else 's'} {seeds_text}"
    else:
        said = f" · seeds {list(seeds)}" if seeds else ""
    text = f"ffjax · preset {preset}{said} · commit {str(commit)[:7]}"
    if preset == "smoke":
        text += " · SMOKE PRESET: plumbing check, numbers meaningless"
    fig.text(0.995, 0.005, text, ha="right", va="bottom", fontsize=7, color="0.35")
