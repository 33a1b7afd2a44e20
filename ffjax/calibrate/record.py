"""Record calibration data from a sensor: frames from the camera, forces typed in or read from a gauge.

    python -m ffjax.calibrate.record --camera 0 --out calib/ [--per-press 5] [--serial /dev/ttyUSB0]

The procedure (paper section IV-B: ~100 labelled frames of one indenter are enough):
  1. Mount the sensor gel-up, rigidly. Print the Big Sphere indenter (the same shape as in training) with a
     flat top or a tray that holds calibration weights, and a loose vertical guide so it cannot tip.
  2. Start this tool with nothing touching the gel: it lets the camera settle (--warmup frames), then
     averages --bg-frames frames into the background.
  3. For each press: place the indenter (and weights) on the gel, wait for it to settle, type the force and
     press Enter. A plain number is Fz in newtons; "200g" (or "0.2kg") is a mass, Fz = m * 9.81 N; "fx fy
     fz" gives all three (an inclined mount). With --serial the force gauge is read instead (Enter alone).
     --per-press frames are saved per press (vary the position slightly between presses).
  4. Cover the force range you will use, light to heavy, ~20 weights x 5 frames. Type "q" to finish.
Output (the FeelAnyForce release layout, readable by `python -m ffjax.calibrate --data OUT/data.csv`):
OUT/data.csv (tactile, FT = "Fx Fy Fz 0 0 0"), OUT/tactile/000000.png ..., OUT/background.png. The CSV is
rewritten after every press, so an interrupted session keeps what it recorded; re-running with the same
--out appends (with its own background_<k>.png and a per-row background column). OUT is locked while a
session records: a second session into it stops at once, naming the first (it would rewrite the CSV
without the first one's rows).

Serial gauges: pyserial (`pip install pyserial`) is imported only with --serial. The gauge must answer a
line containing a number in newtons; --serial-query sends a request first (e.g. '?' for Mark-10 gauges).
"""

from __future__ import annotations

import argparse
import csv
import io
import re
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np

from ffjax import cli
from ffjax.data.csv_source import CSV_NAME
from ffjax.data.images import BACKGROUND_NAME, write_rgb
from ffjax.data.validate import NUMBER, plain_number
from ffjax.files import atomic_write_text, folder_lock

G = 9.81


def parse_force(text: str) -> np.ndarray:
    """'2.5' -> (0, 0, 2.5) N; '200g' / '0.2 kg' -> (0, 0, m * 9.81); '0.1 -0.2 3' -> (0.1, -0.2, 3)."""
    s = text.strip().lower().replace(",", " ")
    m = re.fullmatch(rf"({NUMBER})\s*(g|kg)", s)
    if m:
        mass = float(m.group(1)) * (1e-3 if m.group(2) == "g" else 1.0)
        return np.array([0.0, 0.0, mass * G], np.float32)
    values = [plain_number(p) for p in s.removesuffix("n").split()]  # float() would read "1_0" as 10, take "nan"
    if None in values:
        raise ValueError(f"cannot read a force from {text!r}: type Fz in N, a mass like 200g, or 'fx fy fz'")
    if len(values) == 1:
        return np.array([0.0, 0.0, values[0]], np.float32)
    if len(values) == 3:
        return np.asarray(values, np.float32)
    raise ValueError(f"{text!r}: give 1 (Fz) or 3 (Fx Fy Fz) numbers")


class Recorder:
    """Appends labelled frames to a release-layout folder; the CSV is rewritten atomically each time.

    One session: background.png beside the CSV. A later session into the same folder saves its own
    background_<k>.png and the CSV gets a per-row `background` column (the loader reads either)."""

    def __init__(self, out, background: np.ndarray):
        self.out = Path(out)
        (self.out / "tactile").mkdir(parents=True, exist_ok=True)
        self.rows: list[list[str]] = []  # [tactile, FT, background]
        csv_path = self.out / CSV_NAME
        if csv_path.is_file():  # continue an earlier session
            with open(csv_path, newline="") as f:
                self.rows = [[r["tactile"], r["FT"], r.get("background") or BACKGROUND_NAME]
                             for r in csv.DictReader(f)]
        bg_name = BACKGROUND_NAME
        if self.rows:
            k = 1
            while (self.out / f"background_{k}.png").exists():
                k += 1
            bg_name = f"background_{k}.png"
        write_rgb(self.out / bg_name, background)
        self.background, self.bg_name = background, bg_name

    def add(self, frame: np.ndarray, force) -> None:
        frame = np.asarray(frame)
        if frame.shape != self.background.shape or frame.dtype != np.uint8:
            raise ValueError(f"frame {frame.shape} {frame.dtype} does not match the background "
                             f"{self.background.shape} uint8")
        rel = f"tactile/{len(self.rows):06d}.png"
        write_rgb(self.out / rel, frame)
        f = np.asarray(force, np.float64).reshape(3)
        self.rows.append([rel, " ".join(f"{v:.6g}" for v in f) + " 0 0 0", self.bg_name])

    def flush(self) -> Path:
        path = self.out / CSV_NAME
        per_row = any(r[2] != BACKGROUND_NAME for r in self.rows)
        text = io.StringIO()
        w = csv.writer(text)
        w.writerow(["tactile", "FT"] + (["background"] if per_row else []))
        w.writerows(r if per_row else r[:2] for r in self.rows)
        atomic_write_text(path, text.getvalue())
        return path


def mean_frame(frames: Iterator[np.ndarray], n: int) -> np.ndarray:
    return np.mean([next(frames) for _ in range(n)], axis=0).round().astype(np.uint8)


def session(frames: Iterator[np.ndarray], ask: Callable[[int], str | None], out, per_press: int = 5,
            warmup: int = 30, bg_frames: int = 10, log=print) -> Path:
    """The recording loop with its I/O injected: `frames` yields RGB uint8 frames (the camera), `ask(i)`
    returns the typed answer for press i ("" / "q" / None ends). Returns the CSV path. `out` is locked
    throughout (FolderLockedError if another session holds it)."""
    with folder_lock(out, "calibration recording"):
        return _session(frames, ask, Path(out), per_press, warmup, bg_frames, log)


def _session(frames, ask, out: Path, per_press: int, warmup: int, bg_frames: int, log) -> Path:
    for _ in range(warmup):
        next(frames)
    rec = Recorder(out, mean_frame(frames, bg_frames))
    log(f"background taken ({bg_frames} frames); {len(rec.rows)} rows already in {rec.out}")
    i = 0
    while True:
        answer = ask(i)
        if answer is None or answer.strip().lower() in ("", "q", "quit"):
            break
        try:
            force = parse_force(answer)
        except ValueError as e:
            log(f"  {e}")
            continue
        for _ in range(per_press):
            rec.add(next(frames), force)
        rec.flush()
        log(f"  press {i}: F = {force.round(4).tolist()} N, {per_press} frames ({len(rec.rows)} rows)")
        i += 1
    return rec.flush()


def camera_frames(index: int, flush: int = 4) -> Iterator[np.ndarray]:
    """RGB frames from cv2.VideoCapture(index); `flush` stale buffered frames are dropped before each, so
    a frame read after the user pressed Enter shows the present, not the past."""
    cap = cv2.VideoCapture(index)
    if not cap.isOpened():
        raise RuntimeError(f"cannot open camera {index} (is the sensor plugged in? try another index)")
    try:
        while True:
            for _ in range(flush):
                cap.grab()
            ok, frame = cap.read()
            if not ok:
                raise RuntimeError(f"camera {index} stopped delivering frames")
            yield np.ascontiguousarray(frame[..., ::-1])
    finally:
        cap.release()


def serial_reader(port: str, baud: int = 9600, query: str | None = None, timeout: float = 2.0):
    """A function returning one gauge reading (N) per call, as text for parse_force; needs pyserial."""
    try:
        import serial  # pyserial: optional
    except ImportError:
        raise SystemExit("--serial needs pyserial: pip install pyserial") from None
    dev = serial.Serial(port, baud, timeout=timeout)

    def read() -> str:
        dev.reset_input_buffer()
        if query:
            dev.write((query + "\r\n").encode())
        line = dev.readline().decode(errors="replace")
        m = re.search(NUMBER, line)
        if not m:
            raise ValueError(f"no number in the gauge's reply {line!r}")
        return m.group(0)

    return read


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m ffjax.calibrate.record", description=cli.description(__doc__),
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(__doc__.splitlines()[1:]))
    p.add_argument("--camera", type=cli.integer(0), required=True,
                   help="video device index of the sensor, 0 for the first")
    p.add_argument("--out", required=True, help="output folder (data.csv, tactile/, background.png)")
    p.add_argument("--per-press", type=cli.integer(1), default=5, help="frames saved per press (default 5)")
    p.add_argument("--warmup", type=cli.integer(0, "0: none"), default=30,
                   help="frames dropped before the background")
    p.add_argument("--bg-frames", type=cli.integer(1), default=10, help="frames averaged into the background")
    p.add_argument("--resize", type=cli.frame_size, default=None,
                   help="HxW: resize camera frames (match your checkpoint)")
    p.add_argument("--serial", default=None, help="serial port of a force gauge (needs pyserial)")
    p.add_argument("--baud", type=cli.integer(1), default=9600, help="serial line speed of the gauge (default 9600)")
    p.add_argument("--serial-query", default=None, help="text sent to the gauge before each reading")
    a = p.parse_args(argv)
    cli.check_out(p, a.out)  # before the camera: a typo in --out costs no warmup
    frames = camera_frames(a.camera)
    if a.resize:
        h, w = a.resize
        frames = (cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in frames)
    if a.serial:
        gauge = serial_reader(a.serial, a.baud, a.serial_query)

        def ask(i):
            typed = input(f"press {i}: load the gel, Enter to read the gauge (q to finish) > ")
            return typed if typed.strip() else gauge()
    else:
        def ask(i):
            return input(f"press {i}: force (Fz N | 200g | 'fx fy fz'; Enter/q to finish) > ")
    print("keep the gel untouched: taking the background ...")
    try:
        path = session(frames, ask, a.out, a.per_press, a.warmup, a.bg_frames)
    except (KeyboardInterrupt, EOFError):
        print("\nstopped; what was recorded is saved")
        return 0
    print(f"wrote {path}; next: python -m ffjax.calibrate --checkpoint RUN --data {path} --out RUN_calibrated")
    return 0


if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
