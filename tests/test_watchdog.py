"""CI can never hang silently: a test stuck past the suite's timeout (pyproject's [tool.pytest.ini_options]) fails
with every thread's stack, including one stuck where no signal reaches Python (in C code, as XLA's FFTs deadlocked
on jax 0.11)."""

import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_suite_has_a_watchdog_that_ends_a_hung_test_with_its_stack(tmp_path):
    ini = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert ini["timeout_method"] == "thread" and 60 <= int(ini["timeout"]) <= 1800
    (tmp_path / "test_stuck.py").write_text(textwrap.dedent("""
        import threading

        def test_waits_forever():
            threading.Event().wait()  # a wait no KeyboardInterrupt or alarm breaks
    """))
    p = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-o", "timeout=3", "-o",
                        "timeout_method=thread", str(tmp_path / "test_stuck.py")], capture_output=True, text=True,
                       cwd=tmp_path, timeout=120)
    out = p.stdout + p.stderr
    assert p.returncode != 0, out
    assert "Timeout" in out and "test_waits_forever" in out, out
