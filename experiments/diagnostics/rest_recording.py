"""A sensor at rest, measured: per-frame noise, the fixed fine pattern, illumination drift and colour balance,
by one estimator for a real recording and for the simulator's sensors.

    python -m experiments.diagnostics.rest_recording --recording DIR [--sensors KEY ...] [--out DIR]

DIR holds background.png and the frames, DIR/tactile/*.png (the layout of the FeelAnyForce release's
records/calibration_sphere: frames named by their millisecond timestamp; frames with other names are taken
at --fps). The simulator's sensors are rendered untouched at their native size (a GelSight Mini's is the
release's 240x320): their background frame and --sim-frames frames, each with its own camera noise. Per colour channel:
- level: the frames' mean (8-bit counts);
- noise: the per-frame noise, from consecutive frames' difference with its mean removed, / sqrt(2);
- fixed pattern: what every frame shares at fine scale (each frame less its Gaussian blur of HIGHPASS_PX,
  so vignette and lighting are left out), from the cross-covariance between different frames (their noise
  is independent, so it drops out): its rms, in counts and as % of the level, and its gradient's rms (%/px);
- drift: the frames' mean minus the background's, over time (first, most negative, most positive, last), and
  its rate (counts/min, a straight line fitted over the recording);
- the drift's make-up, what a drift augmentation must reproduce: the last frames less the first (a few each,
  blurred by DRIFT_SMOOTH of the frame's width, so noise and the fine pattern drop out), fitted over the pad as
  offset + gain x the first frames' level; per minute of the recording: the gain (% of the level), the offset
  (counts), the rms of what the fit leaves (a smooth field across the pad, counts) and the share of the drift
  map's variance the gain and offset explain.
Frames at rest cannot tell a pattern that moves with the gel (pigment) from one that stays (the camera's pixel
gains, dust on the optics): the fixed pattern is their sum, an upper bound for either.
Writes OUT/results.json, rest_recording.md and rest_recording.png.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import cv2
import numpy as np

from experiments.diagnostics import publish
from ffjax.sim.optics import FINE_PX as HIGHPASS_PX  # the simulator's patterns are scaled by the same estimator

CHANNELS = ("R", "G", "B")
SIM_SENSORS = ("mini-1-gel1", "mini-1-gel2", "mini-1-gel3", "digit")
DRIFT_SMOOTH = 1 / 40  # the drift map's blur, a fraction of the frame's width: far above the fine pattern's scale


def _read_png(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    return img[..., ::-1]  # RGB


def load_recording(folder, fps: float = 30.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frames (N, H, W, 3) uint8 RGB, background (H, W, 3), times (N,) s from the first frame) of a rest
    recording: DIR/background.png and DIR/tactile/*.png (DIR/*.png when there is no tactile/). Times come from
    integer file names (milliseconds), else frame order at `fps`. ValueError naming the file on a bad input."""
    folder = Path(folder)
    bg_file = folder / "background.png"
    if not bg_file.is_file():
        raise ValueError(f"{folder}: no background.png (a rest recording holds background.png and tactile/*.png)")
    frames_dir = folder / "tactile" if (folder / "tactile").is_dir() else folder
    files = sorted(p for p in frames_dir.glob("*.png") if p != bg_file)
    if len(files) < 3:
        raise ValueError(f"{frames_dir}: {len(files)} frames; the estimator needs at least 3")
    stamps = [p.stem for p in files]
    if all(re.fullmatch(r"\d+", s) for s in stamps):
        files = sorted(files, key=lambda p: int(p.stem))
        ms = np.array([int(p.stem) for p in files], np.float64)
        times = (ms - ms[0]) / 1000.0
    else:
        times = np.arange(len(files)) / float(fps)
    background = _read_png(bg_file)
    frames = np.empty((len(files),) + background.shape, np.uint8)
    for i, p in enumerate(files):
        img = _read_png(p)
        if img.shape != background.shape:
            raise ValueError(f"{p}: frame is {img.shape[1]}x{img.shape[0]}, the background "
                             f"{background.shape[1]}x{background.shape[0]}")
        frames[i] = img
    return frames, background, times


def _highpass(img: np.ndarray) -> np.ndarray:
    """A frame less its blur (float32), less its mean per channel."""
    x = img.astype(np.float32)
    out = x - cv2.GaussianBlur(x, (0, 0), HIGHPASS_PX, borderType=cv2.BORDER_REPLICATE)
    return out - out.mean((0, 1))


class _Shared:
    """Per channel, the rms of what a stream of arrays ((K, H, W, 3): K components each, one per frame) has in
    common: the mean over pairs of different frames of <a_i . a_j>, from their sum and sum of squares."""

    def __init__(self):
        self.n, self.total, self.squares = 0, None, np.zeros(3)

    def add(self, a: np.ndarray) -> None:
        self.total = a.astype(np.float64) if self.total is None else self.total + a
        self.squares += np.einsum("khwc,khwc->c", a, a, dtype=np.float64)
        self.n += 1

    def rms(self) -> np.ndarray:
        t = self.total
        cross = (np.einsum("khwc,khwc->c", t, t) - self.squares) / (self.n * (self.n - 1))
        return np.sqrt(np.maximum(cross / (t.shape[1] * t.shape[2]), 0.0))


def measure(frames: np.ndarray, background: np.ndarray, times: np.ndarray) -> dict:
    """The rest statistics of frames (N, H, W, 3) against their background, per channel (R, G, B): see the
    module's docstring. Lists of 3 floats; times (N,) in seconds."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) < 3:
        raise ValueError(f"frames must be (N >= 3, H, W, 3), got {frames.shape}")
    bg = np.asarray(background, np.float64)
    level = frames.mean((0, 1, 2), dtype=np.float64)
    drift = frames.mean((1, 2), dtype=np.float64) - bg.mean((0, 1))  # (N, 3)
    diff_var = np.zeros(3)
    for a, b in zip(frames[:-1], frames[1:]):
        d = b.astype(np.float32) - a.astype(np.float32)
        diff_var += (d - d.mean((0, 1))).var((0, 1))
    noise = np.sqrt(diff_var / (len(frames) - 1) / 2)
    values, slopes = _Shared(), _Shared()
    for f in frames:
        h = _highpass(f)
        values.add(h[None])
        slopes.add(np.stack(np.gradient(h, axis=(0, 1))))
    fixed, gradient = values.rms(), slopes.rms()
    minutes = np.asarray(times, np.float64) / 60.0
    rate = [float(np.polyfit(minutes, drift[:, c], 1)[0]) if np.ptp(minutes) > 0 else 0.0 for c in range(3)]
    out = {"frames": int(len(frames)), "size": list(frames.shape[1:3]), "span_s": float(np.ptp(times)),
           "background_mean": bg.mean((0, 1)).tolist(), "level": level.tolist(), "noise": noise.tolist(),
           "fixed": fixed.tolist(), "fixed_pct": (100 * fixed / level).tolist(),
           "gradient_pct_per_px": (100 * gradient / level).tolist(),
           "drift_first": drift[0].tolist(), "drift_min": drift.min(0).tolist(), "drift_max": drift.max(0).tolist(),
           "drift_last": drift[-1].tolist(), "drift_per_min": rate,
           "drift_curve": {"t_s": np.asarray(times, float).round(3).tolist(), "counts": drift.round(4).tolist()}}
    return {**out, **drift_makeup(frames, times)}


def drift_makeup(frames: np.ndarray, times: np.ndarray) -> dict:
    """The drift between the first and the last few frames (N, H, W, 3) split per channel into a gain, an offset
    and a smooth field left over, each per minute (see the module's docstring)."""
    k = max(1, min(5, len(frames) // 4))
    sigma = DRIFT_SMOOTH * frames.shape[2]

    def smooth(a):
        return cv2.GaussianBlur(a.astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)

    first, last = smooth(frames[:k].mean(0)), smooth(frames[-k:].mean(0))
    minutes = max(float(np.mean(times[-k:]) - np.mean(times[:k])) / 60.0, 1e-9)
    gain, offset, field, explained = [], [], [], []
    for c in range(3):
        level, change = first[..., c].ravel().astype(np.float64), (last - first)[..., c].ravel().astype(np.float64)
        spread = level.var()  # a flat channel cannot tell a gain from an offset: all of it is offset then
        g = float(np.mean((level - level.mean()) * (change - change.mean())) / spread) if spread > 1.0 else 0.0
        o = float(change.mean() - g * level.mean())
        left = change - o - g * level
        gain.append(100 * g / minutes)
        offset.append(o / minutes)
        field.append(float(np.sqrt(np.mean(left ** 2))) / minutes)
        explained.append(float(1 - left.var() / change.var()) if change.var() > 0 else 0.0)
    return {"drift_gain_pct_per_min": gain, "drift_offset_per_min": offset, "drift_field_rms_per_min": field,
            "drift_level_fit_share": explained}


def simulated(key: str, n: int, interval_s: float) -> tuple:
    """(frames, background, times) of the simulator's sensor `key` at rest, at its native size: its background
    frame and n frames of the untouched gel, each with its own camera noise, interval_s apart."""
    from ffjax.sim import optics
    from ffjax.sim.sensors import get_sensor

    sensor = get_sensor(key)
    size = tuple(sensor.native_size)
    flat = np.zeros(size, np.float32)
    frames = np.stack([optics.render(sensor, size, flat, None, seed=1_000_003 + i) for i in range(n)])
    return frames, sensor.background(size), np.arange(n) * interval_s


def report(res: dict) -> str:
    """Markdown: one row per source and channel."""
    cols = ["source", "ch", "background mean", "noise", "fixed pattern", "fixed %", "gradient %/px",
            "drift last", "drift /min"]
    lines = [f"# A sensor at rest: the real recording against the simulator (commit `{res['commit'][:7]}`)", "",
             f"Estimator: experiments.diagnostics.rest_recording (high-pass sigma {res['highpass_px']} px, "
             "fixed pattern from the cross-covariance of different frames, counts of 8 bits).", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for name, s in res["sources"].items():
        for c, ch in enumerate(CHANNELS):
            lines.append(f"| {name} | {ch} | {s['background_mean'][c]:.1f} | {s['noise'][c]:.2f} | "
                         f"{s['fixed'][c]:.2f} | {s['fixed_pct'][c]:.2f} | {s['gradient_pct_per_px'][c]:.2f} | "
                         f"{s['drift_last'][c]:+.2f} | {s['drift_per_min'][c]:+.2f} |")
    lines += ["", "The drift's make-up per minute (the last frames less the first, smoothed, fitted as offset + gain x "
              "level):",
              "", "| source | ch | gain %/min | offset counts/min | field rms counts/min | share fitted |",
              "|---|---|---|---|---|---|"]
    for name, s in res["sources"].items():
        if "drift_gain_pct_per_min" not in s:  # a result made before the make-up was measured
            continue
        for c, ch in enumerate(CHANNELS):
            lines.append(f"| {name} | {ch} | {s['drift_gain_pct_per_min'][c]:+.2f} | "
                         f"{s['drift_offset_per_min'][c]:+.2f} | {s['drift_field_rms_per_min'][c]:.2f} | "
                         f"{s['drift_level_fit_share'][c]:.2f} |")
    real = res.get("real")
    if real:
        s = res["sources"][real]
        lines += ["", f"{real}: {s['frames']} frames over {s['span_s']:.0f} s at {s['size'][1]}x{s['size'][0]} "
                  f"({res['recording']})."]
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> Path:
    """The drift over time (each source, per channel) and the per-channel noise, fixed pattern and gradient."""
    from experiments import common, style
    from experiments.tables import save_png

    names = list(res["sources"])
    colours = ("tab:red", "tab:green", "tab:blue")
    fig, axes = style.figure(1, 4, figsize=(15, 3.6))
    ax = axes[0]
    for name in names:
        s = res["sources"][name]
        t, counts = np.asarray(s["drift_curve"]["t_s"]), np.asarray(s["drift_curve"]["counts"])
        style = "-" if name == res.get("real") else ":"
        for c in range(3):
            ax.plot(t, counts[:, c], style, color=colours[c], lw=1.2 if style == "-" else 0.8)
    ax.set(xlabel="time (s)", ylabel="frame mean - background (counts)",
           title="drift at rest (solid: real, dotted: simulated)")
    ax.axhline(0, color="0.6", lw=0.6)
    for ax, key, title in zip(axes[1:], ("noise", "fixed_pct", "gradient_pct_per_px"),
                              ("per-frame noise (counts)", "fixed fine pattern (% of level)",
                               "its gradient (% of level per px)")):
        x = np.arange(len(names))
        for c in range(3):
            ax.bar(x + (c - 1) * 0.26, [res["sources"][n][key][c] for n in names], 0.26, color=colours[c],
                   label=CHANNELS[c])
        ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
        ax.set_title(title, fontsize=10)
    for ax, key in zip(axes[2:], ("fixed_pct", "gradient_pct_per_px")):
        values = [v for n in names for v in res["sources"][n][key]]
        if max(values) > 5 * min(values):  # a marker gel's dots are a fixed pattern ten times a pigment's
            ax.set_yscale("log")
    axes[1].legend(fontsize=7)
    common.stamp(fig, res.get("preset", "native"), [], res["commit"])
    return save_png(fig, Path(path))


def main(argv=None) -> dict:
    from experiments import common
    from ffjax import cli

    ap = argparse.ArgumentParser(prog=common.prog(), description=common.description(__doc__))
    ap.add_argument("--recording", default=None, help="a real rest recording: DIR/background.png and DIR/tactile/*.png")
    ap.add_argument("--name", default="GelSight Mini (real)", help="the recording's name in the tables")
    ap.add_argument("--source", default=None, help="where the recording comes from, for the report (default: DIR)")
    ap.add_argument("--fps", type=cli.number(0), default=30.0, help="frame rate when frame names are not timestamps")
    ap.add_argument("--sensors", nargs="*", default=list(SIM_SENSORS), help="simulated sensors to measure")
    ap.add_argument("--sim-frames", type=cli.integer(1), default=40, help="frames per simulated sensor (default 40)")
    ap.add_argument("--out", default=None, help="results folder (default: results/rest_recording)")
    args = ap.parse_args(argv)
    if args.sim_frames < 3:
        ap.error("--sim-frames must be at least 3")
    out = cli.check_out(ap, Path(args.out or common.ROOT / "results" / "rest_recording"))
    res = {"commit": common.git_commit(), "preset": "native", "highpass_px": HIGHPASS_PX, "sources": {},
           "real": None, "recording": None}
    interval = 1.5  # s between simulated frames without a recording (only the drift plot's time axis)
    if args.recording:
        frames, background, times = load_recording(args.recording, args.fps)
        res["sources"][args.name] = measure(frames, background, times)
        res["real"], res["recording"] = args.name, args.source or str(Path(args.recording))
        interval = float(np.ptp(times) / (args.sim_frames - 1))  # the simulated frames span the same time
    for key in args.sensors:
        res["sources"][key] = measure(*simulated(key, args.sim_frames, interval))
    return publish(out, "rest_recording", res, report, plot)


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
