"""Command line tools answer a bad argument with one `error:` line and exit code 2, not a traceback."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("cmd, fragment", [
    (["ffjax.live", "--checkpoint", "{tmp}/nope", "--video", "x.mp4", "--headless"], "nope"),
    (["ffjax.export", "--checkpoint", "{tmp}/nope", "--out", "{tmp}/ex"], "no such checkpoint folder"),
    (["experiments.ablation", "--preset", "smoke", "--methods", "bogus", "--out", "{tmp}/abl"],
     "unknown method 'bogus'"),
    (["experiments.ablation", "--preset", "smoke", "--out", "/dev/null/abl"], "--out: output folder /dev/null/abl"),
])
def test_bad_arguments_are_one_line_errors(tmp_path, cmd, fragment):
    env = {**os.environ, "FFJAX_DEBUG": ""}
    p = subprocess.run([sys.executable, "-m", *(c.format(tmp=tmp_path) for c in cmd)], capture_output=True,
                       text=True, cwd=ROOT, env=env, timeout=300)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2, p.stderr
    assert any((ln.startswith("error: ") or ": error: " in ln) and fragment in ln for ln in lines), p.stderr
    assert "Traceback" not in p.stderr
