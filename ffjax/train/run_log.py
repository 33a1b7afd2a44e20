"""A run's logs: train_log.jsonl (a row per logged step and per validation) and epochs.csv (a row per epoch),
appended as training goes and cut back to the restored step on resume (a torn last line is dropped)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from ffjax.files import atomic_write_text

LOG_NAME, CSV_NAME = "train_log.jsonl", "epochs.csv"


def csv_fields(objective) -> tuple[str, ...]:
    """epochs.csv's columns: the epoch's train means (loss, and each objective term with a train column), its
    validation (loss, each term, the force metric per axis), and the elapsed time."""
    return (
        "epoch",
        "step",
        "train_loss",
        *(f"train_{t.name}" for t in objective.terms if t.train_column),
        "val_loss",
        *(f"val_{name}" for name in objective.names),
        "val_nl1",
        "val_nl1_fx",
        "val_nl1_fy",
        "val_nl1_fz",
        "val_mae_fx",
        "val_mae_fy",
        "val_mae_fz",
        "time_s",
    )


def val_columns(val: dict, objective) -> dict:
    """epochs.csv's validation columns from a `validation.run` result."""
    row = {"val_loss": val["loss"], **{f"val_{name}": val[name] for name in objective.names}, "val_nl1": val["nl1"]}
    row.update({f"val_nl1_{a}": v for a, v in zip(("fx", "fy", "fz"), val["nl1_axes"])})
    row.update({f"val_mae_{a}": v for a, v in zip(("fx", "fy", "fz"), val["mae_n"])})
    return row


class RunLog:
    """JSONL (every row) + CSV (one row per epoch); on resume rows past the restored step are dropped."""

    def __init__(self, run_dir: Path, keep_until: int | None, fields: tuple[str, ...]):
        self.jsonl, self.csv, self.fields = run_dir / LOG_NAME, run_dir / CSV_NAME, fields
        if keep_until is None:
            for p in (self.jsonl, self.csv):
                p.unlink(missing_ok=True)
        else:
            self._truncate(keep_until)

    def _truncate(self, step: int) -> None:
        if self.jsonl.exists():
            rows = [r for r in self.jsonl.read_text().splitlines() if (_json_step(r) or step + 1) <= step]
            atomic_write_text(self.jsonl, "".join(r + "\n" for r in rows))
        if self.csv.exists():
            with self.csv.open() as f:
                rows = [r for r in csv.DictReader(f) if _complete(r) and (_int(r.get("step")) or step + 1) <= step]
            atomic_write_text(self.csv, _csv_text(rows, self.fields))

    def row(self, row: dict) -> None:
        with self.jsonl.open("a") as f:
            f.write(json.dumps(row) + "\n")

    def epoch(self, row: dict) -> None:
        self._write_csv([row], "a")

    def _write_csv(self, rows, mode: str) -> None:
        if mode == "w" or not self.csv.exists():
            atomic_write_text(self.csv, _csv_text(rows, self.fields))
            return
        with self.csv.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=self.fields, extrasaction="ignore").writerows(rows)


def _csv_text(rows, fields) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def _json_step(line: str):
    """A log line's step, or None for a line a kill cut short (dropped on resume)."""
    try:
        return int(json.loads(line)["step"])
    except (ValueError, KeyError, TypeError):
        return None


def _complete(row: dict) -> bool:
    """False for a CSV row a kill cut short (fields missing) or garbled (extra fields)."""
    return None not in row and all(v is not None for v in row.values())


def _int(text):
    try:
        return int(text)
    except (TypeError, ValueError):
        return None
