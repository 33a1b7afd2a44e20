"""ffjax.compile_cache: one configured home for jax's compiled programs, keyed by jax and the CPU."""

import json
import os
import subprocess
import sys

from ffjax import compile_cache

_PROBE = ("import json, jax, jax.numpy as jnp; from ffjax import compile_cache; d = compile_cache.enable(); "
          "jax.jit(lambda x: jnp.sin(x) * 3 + x)(jnp.arange(5.0)).block_until_ready(); "
          "print(json.dumps({'dir': d and str(d), 'config_dir': jax.config.jax_compilation_cache_dir, "
          "'min_s': jax.config.jax_persistent_cache_min_compile_time_secs, 'key': compile_cache.key()}))")


def _in_a_fresh_process(env: dict, home) -> dict:
    """What enable() returns and leaves in jax's config, in a process of its own (jax's cache is process-wide)."""
    env = {**{k: v for k, v in os.environ.items() if k != "FFJAX_CACHE"}, "HOME": str(home), **env}
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_cache_keeps_every_program_under_its_key(tmp_path):
    """FFJAX_CACHE names the folder, the key its sub-folder; programs that compile in well under jax's default 1 s
    threshold are kept too; a second process loads the program the first compiled (it adds no entry)."""
    got = _in_a_fresh_process({"FFJAX_CACHE": str(tmp_path / "c")}, tmp_path)
    want = tmp_path / "c" / "xla" / got["key"]
    assert got["dir"] == got["config_dir"] == str(want) and got["min_s"] == 0.0
    entries = sorted(p.name for p in want.iterdir())
    assert entries
    _in_a_fresh_process({"FFJAX_CACHE": str(tmp_path / "c")}, tmp_path)
    assert sorted(p.name for p in want.iterdir()) == entries


def test_off_leaves_jax_alone_and_the_default_is_in_the_home_folder(tmp_path):
    off = _in_a_fresh_process({"FFJAX_CACHE": "off"}, tmp_path)
    assert off["dir"] is None and not off["config_dir"] and off["min_s"] > 0
    home = _in_a_fresh_process({}, tmp_path / "home")
    assert home["dir"] == str(tmp_path / "home" / ".cache" / "ffjax" / "xla" / home["key"])


def test_another_cpu_or_jax_reads_another_folder(monkeypatch):
    """XLA compiles CPU programs for the host's instruction set: an entry of another CPU must not be read."""
    here = compile_cache.key()
    assert here.startswith(f"jax{compile_cache.jax.__version__}-")
    monkeypatch.setattr(compile_cache, "_cpu", lambda: "model name=another|flags=sse2")
    assert compile_cache.key() != here
    monkeypatch.setattr(compile_cache.jax, "__version__", "0.0.1")
    assert compile_cache.key().startswith("jax0.0.1-")


def test_a_pooled_training_worker_uses_the_cache(tmp_path):
    """experiments.kernel's worker processes (spawned: they inherit no jax config) turn the cache on at their start:
    they had compiled every run's programs afresh, the ablation's and the sweep's included."""
    import concurrent.futures
    import multiprocessing

    from experiments import kernel

    ctx = multiprocessing.get_context("spawn")
    shares = ctx.Queue()
    shares.put(set(os.sched_getaffinity(0)))
    os.environ["FFJAX_CACHE"], old = str(tmp_path / "c"), os.environ.get("FFJAX_CACHE")
    try:
        with concurrent.futures.ProcessPoolExecutor(1, mp_context=ctx, initializer=kernel._pin,
                                                    initargs=(shares,)) as pool:
            used = pool.submit(_cache_dir_in_worker).result()
    finally:
        os.environ.pop("FFJAX_CACHE") if old is None else os.environ.__setitem__("FFJAX_CACHE", old)
    assert used == str(tmp_path / "c" / "xla" / compile_cache.key())


def _cache_dir_in_worker() -> str:
    import jax

    return jax.config.jax_compilation_cache_dir
