"""One experiment run: a method x seed trained, evaluated (Tables I-III) and timed in its folder, and reused
when a folder already holds it finished. The experiments that train (ablation, sweep_loss, pareto, stability,
downstream's fallback run) train and score through here.

    folder = run_dir(out, "dino_rd", 0)                # OUT/runs/dino_rd/seed0 (a sized cell: OUT/runs/<size>/...)
    r = run(cfg, spec, seed, data_root, out, backbone=lambda: pretrained_backbone(...), reuse_from=ablation_dir)
    r.dir, r.result, r.train_s, r.eval_s, r.reused

Caching: training is a `common.Stage` keyed by `train_key` (the data/model/train/pretrain config, the
method's spec, the seed and the dataset's config); a finished stage is not redone, a partial one resumes
from its checkpoints. The evaluation is cached in RUN/eval.json under a key of the run's stage.json and the
calibration config. A folder of another experiment (`reuse_from`, an ablation's) is used as it stands when
its stage holds the same key and is done.

Several runs: `run_all(jobs, workers=2)` trains (and evaluates) the jobs that need training two at a time, each
in its own process pinned to its half of the cores (common.default_workers: on a CPU). On the 2-core CPU a quick
train step on two cores takes well over half its time on one, so two runs side by side finish sooner than one
after the other (measured: docs/experiments.md). Their recorded train seconds are then one core's, beside another
run.
"""

from __future__ import annotations

import concurrent.futures
import copy
import dataclasses
import multiprocessing
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

import configs
from experiments import common, paper_numbers

# Table III: (target sensor, which layers calibrate): GelSight units tune the last Linear + LayerNorm,
# DIGIT (another kind of sensor) the whole regressor, as the paper does.
CALIBRATIONS = (("mini-2-gel1", "last"), ("mini-3-gel2", "last"), ("digit", "regressor"))


@dataclasses.dataclass(frozen=True)
class Run:
    """A trained and evaluated run: its folder, its Tables I-III numbers, the wall seconds training and
    evaluating took in this call (near 0 when cached) and whether it is another experiment's folder, reused."""

    dir: Path
    result: dict
    train_s: float
    eval_s: float
    reused: bool


def run_dir(out, method: str, seed: int, size: str | None = None) -> Path:
    """OUT/runs/<method>/seed<k>, or OUT/runs/<size>/<method>/seed<k> for a backbone size other experiments
    do not share (pareto): the layout results.json's "checkpoints" name and later experiments reuse."""
    runs = Path(out) / "runs"
    return (runs / size if size else runs) / method / f"seed{seed}"


def seeds(cfg: dict, n: int) -> list[int]:
    """The n training seeds of a sweep: the config's seed and the ones after it."""
    return [int(cfg["seed"]) + k for k in range(n)]


def seeds_for(cfg: dict, spec, n: int, data_root: Path, reuse_from=None) -> list[int]:
    """A cell's n seeds, then every further seed reuse_from (an ablation folder) finished with the same training
    key: its extra seeds cost nothing and narrow the cell's error bar."""
    own = seeds(cfg, n)
    if reuse_from is None:
        return own
    found = sorted(int(p.name[4:]) for p in (Path(reuse_from) / "runs" / spec.name).glob("seed*")
                   if p.name[4:].isdigit())
    return own + [s for s in found if s not in own and reusable(reuse_from, cfg, spec, s, data_root)]


def train_key(cfg: dict, spec, seed: int, data_root: Path) -> str:
    """The training stage's key: what decides the trained weights (not paths, not progress bars)."""
    manifest = common.read_json(Path(data_root) / "manifest.json") or {}
    # keys the config gained in issue 15 are left out at their old values: runs trained before stay valid
    keyed = configs.without_before_keys({k: cfg[k] for k in ("data", "model", "train", "pretrain")})
    return common.fingerprint("train", keyed, spec.__dict__, seed, manifest.get("config"))


def trained(folder: Path, cfg: dict, spec, seed: int, data_root: Path) -> bool:
    """Whether folder holds this method and seed trained to the end with the same key."""
    info = common.read_json(Path(folder) / "stage.json") or {}
    return info.get("status") == "done" and info.get("key") == train_key(cfg, spec, seed, data_root)


def reusable(reuse_from, cfg: dict, spec, seed: int, data_root: Path) -> Path | None:
    """reuse_from's run folder for this method and seed (absolute) when it finished training with the same
    key, else None (also when reuse_from is None)."""
    if reuse_from is None:
        return None
    folder = run_dir(reuse_from, spec.name, seed).absolute()
    return folder if trained(folder, cfg, spec, seed, data_root) else None


def pretraining_corpus(cfg: dict, kinds, data_root: Path, force: bool, progress: bool) -> bool:
    """Build (or find) the unlabeled corpus the backbones of `kinds` pretrain on, when one of them will pretrain;
    True when it was needed. The backbones share it: timed apart, the first backbone's time is its own."""
    from ffjax.train import pretrain

    root = Path(data_root) / "pretrained"
    if not force and all(pretrain.is_cached(cfg, kind, root / kind) for kind in kinds):
        return False
    pretrain.corpus.load_or_build(cfg, root, progress=progress)
    return True


def pretrained_backbone(cfg: dict, kind: str, data_root: Path, force: bool, progress: bool):
    """(params, batch_stats) of the preset's cached self-supervised backbone, pretraining it on first use."""
    from ffjax.train import pretrain

    folder = Path(data_root) / "pretrained" / kind
    pretrain.ensure(cfg, kind, folder, force=force, progress=progress)
    return pretrain.load_backbone(folder)


def train(cfg: dict, spec, seed: int, data_root: Path, folder: Path, backbone: Callable | None = None,
          force: bool = False, progress: bool = True) -> None:
    """Train one method/seed in `folder`, or leave it when finished, or resume it if a kill left it partial.
    backbone: called (only when training happens) for the initial (params, batch_stats) of a pretrained
    method; a method that does not start pretrained never gets one."""
    from ffjax import train as train_lib

    stage = common.Stage(folder, train_key(cfg, spec, seed, data_root), force)
    if stage.done:
        return
    run_cfg = copy.deepcopy(cfg)
    run_cfg["seed"] = seed
    init = backbone() if backbone is not None and spec.pretrained else None
    train_lib.train(run_cfg, spec, data_root, folder, resume=(folder / "checkpoints").exists(), init_backbone=init,
                    progress=progress)
    stage.finish()


def evaluate(cfg: dict, folder: Path, data_root: Path, force: bool = False) -> dict:
    """Tables I-III numbers of one trained run (cached in RUN/eval.json).

    Every test split goes through the backbone once; the regressor (before and after each calibration)
    then runs on the cached features, which is exact because calibration never touches the backbone.
    """
    key = common.fingerprint("eval", common.read_json(folder / "stage.json"), cfg["calibrate"], 2)
    cached = common.read_json(folder / "eval.json")
    if cached and cached.get("key") == key and not force:
        return cached["result"]
    from ffjax.sim import dataset

    ev = _Evaluator(folder, data_root)
    sensors = {s: ev.features("sensor", s) for s in dataset.SENSOR_KEYS}
    result = {"table1": {o: ev.score(ev.reg, ev.features("unseen", o)) for o in paper_numbers.OBJECTS},
              "table2": {s: ev.score(ev.reg, fx) for s, fx in sensors.items()}}
    result["table3"] = {target: _calibration(cfg, ev, target, layers, sensors, result["table2"])
                        for target, layers in CALIBRATIONS}
    common.write_json(folder / "eval.json", {"key": key, "result": result})
    return result


class _Evaluator:
    """A run's model, its regressor and the scoring of (features, forces) pairs."""

    def __init__(self, folder: Path, data_root: Path):
        from ffjax import calibrate, store

        trained = store.load(folder)
        self.stats, self.variables, self.size, self.model = (trained.stats, trained.variables, trained.input_size,
                                                             trained.build())
        self.head = trained.cfg["model"]["regressor"]
        self.reg = self.variables["params"]["regressor"]
        self.reg_stats = calibrate.regressor_stats(self.variables)
        self.data_root = data_root

    def features(self, kind: str, name: str):
        """(backbone features, forces) of one test split."""
        from ffjax import calibrate, data
        from ffjax.sim import dataset

        split = data.open_split(dataset.split_dir(self.data_root, kind, name))
        arr = data.load_arrays(split, self.stats, self.size)
        return calibrate.features(self.model, self.variables, arr["image"]), arr["force"]

    def score(self, reg_params, fx) -> dict:
        from ffjax import calibrate, metrics

        pred = calibrate.predict_from_features(self.head, reg_params, fx[0], self.reg_stats)
        return metrics.summarize(pred, fx[1], self.stats.force_min, self.stats.force_max)


def _calibration(cfg: dict, ev: _Evaluator, target: str, layers: str, sensors: dict, table2: dict) -> dict:
    """Table III for one target sensor: its error before and after calibrating `layers` on its calibration
    split, and what the calibration does to the other GelSight sensors."""
    from ffjax import calibrate

    cc = cfg["calibrate"]
    tuned = calibrate.fit_regressor(ev.head, ev.reg, *ev.features("calib", target), layers=layers,
                                    steps=int(cc["steps"]), lr=float(cc["lr"]), batch_size=int(cc["batch_size"]),
                                    seed=int(cfg["seed"]), reg_stats=ev.reg_stats)
    others = [s for s in paper_numbers.SENSORS if s != target]
    before = {s: table2[s]["nl1"] for s in others}
    after = {s: ev.score(tuned, sensors[s])["nl1"] for s in others}
    return {
        "layers": layers,
        "before": table2[target],
        "after": ev.score(tuned, sensors[target]),
        "others_before": float(np.mean(list(before.values()))),
        "others_after": float(np.mean(list(after.values()))),
        # relative change of the uncalibrated GelSight sensors' error, percent (paper: 4% for DINO RD)
        "degradation_pct": float(np.mean([(after[s] - before[s]) / before[s] * 100 for s in others])),
    }


def run(cfg: dict, spec, seed: int, data_root: Path, out, *, backbone: Callable | None = None, reuse_from=None,
        size: str | None = None, force: bool = False, progress: bool = True) -> Run:
    """One method x seed, trained and evaluated: reuse_from's finished run with the same training key when
    there is one (pass None to never reuse), else run_dir(out, spec.name, seed, size) trained (cached, resumed)
    here. The evaluation is cached in the run's folder either way; `force` redoes what is done here."""
    t = time.perf_counter()
    folder = reusable(reuse_from, cfg, spec, seed, data_root)
    reused = folder is not None
    if not reused:
        folder = run_dir(out, spec.name, seed, size)
        train(cfg, spec, seed, data_root, folder, backbone, force, progress)
    train_s = round(time.perf_counter() - t, 1)
    t = time.perf_counter()
    result = evaluate(cfg, folder, data_root, force)
    return Run(folder, result, train_s, round(time.perf_counter() - t, 1), reused)


@dataclasses.dataclass(frozen=True)
class Job:
    """One method x seed for run_all: run()'s arguments."""

    cfg: dict
    spec: object
    seed: int
    data_root: Path
    out: Path
    backbone: Callable | None = None
    reuse_from: Path | None = None
    size: str | None = None

    def folder(self) -> Path:
        """Where run() trains it (absolute) when it is not reused."""
        return run_dir(self.out, self.spec.name, self.seed, self.size).absolute()

    def needs_training(self, force: bool) -> bool:
        if reusable(self.reuse_from, self.cfg, self.spec, self.seed, self.data_root) is not None:
            return False
        return force or not trained(self.folder(), self.cfg, self.spec, self.seed, self.data_root)


def run_all(jobs: list[Job], workers: int = 1, force: bool = False, progress: bool = True,
            desc: str = "runs") -> list[Run]:
    """run() for every job, in order. With workers > 1, the jobs that need training are trained and evaluated
    `workers` at a time first, each worker process pinned to its share of the cores; the odd ones left over train
    here on every core (alone on one core a run would take longer), as does a size with a lone run (_poolable).
    A pooled run's train_s / eval_s are the seconds its worker took."""
    pooled = {}
    pending = _poolable([j for j in jobs if j.needs_training(force)], workers) if workers > 1 else []
    if pending:
        pooled = _train_pooled(pending, workers, force, progress, desc)
    runs = []
    for job in tqdm(jobs, desc=desc, disable=not progress or len(jobs) < 2 or bool(pooled)):
        r = run(job.cfg, job.spec, job.seed, job.data_root, job.out, backbone=job.backbone,
                reuse_from=job.reuse_from, size=job.size, force=force and job.folder() not in pooled,
                progress=progress)
        if job.folder() in pooled and not r.reused:
            r = dataclasses.replace(r, train_s=pooled[job.folder()][0], eval_s=pooled[job.folder()][1])
        runs.append(r)
    return runs


def _poolable(pending: list[Job], workers: int) -> list[Job]:
    """The jobs worth a pool: per model size (Job.size), whole groups of `workers`. Runs of one size take about as
    long, so a pool of them keeps every core busy to the end; a lone run of another size would train on one core
    while the other idles (as pareto's one-seed vit-m run once did beside a far shorter vit-xs run, taking longer
    than the whole cell takes on both cores), so it trains here on every core."""
    by_size: dict = {}
    for job in pending:
        by_size.setdefault(job.size, []).append(job)
    return [j for group in by_size.values() for j in group[:len(group) - len(group) % workers]]


def _train_pooled(jobs: list[Job], workers: int, force: bool, progress: bool, desc: str) -> dict:
    """Train and evaluate jobs in `workers` spawned processes, each pinned to a disjoint share of this process's
    cores; {folder: (train_s, eval_s)}. The backbones load here (pretraining, if needed, on every core) and
    travel as numpy arrays. A failed run stops the rest and raises, naming its folder; finished runs stay."""
    import jax

    cores = sorted(os.sched_getaffinity(0))
    ctx = multiprocessing.get_context("spawn")  # jax's threads do not survive a fork
    shares = ctx.Queue()
    for share in np.array_split(cores, workers):
        shares.put({int(c) for c in share})
    # before the workers start: a backbone pretrained here has every core to itself
    inits = [jax.tree.map(np.asarray, job.backbone()) if job.backbone is not None and job.spec.pretrained else None
             for job in jobs]
    done = {}
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_pin,
                                                initargs=(shares,)) as pool:
        futures = {pool.submit(_train_and_evaluate, dataclasses.replace(job, backbone=None), init, force): job
                   for job, init in zip(jobs, inits, strict=True)}
        bar = tqdm(total=len(jobs), desc=f"{desc} ({workers} at a time)", disable=not progress)
        try:
            for future in concurrent.futures.as_completed(futures):
                folder = futures[future].folder()
                try:
                    done[folder] = future.result()
                except Exception as e:
                    raise RuntimeError(f"training {folder} in a worker process failed: {e}") from e
                bar.update()
        except BaseException as e:
            if isinstance(e, KeyboardInterrupt):
                # a worker inside XLA (compiling a step takes seconds) sees Ctrl-C only once it is back in Python:
                # stop them now. Nothing is lost: every file is written atomically, and a run resumes from its
                # last checkpoint
                for proc in list(pool._processes.values()):
                    proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        finally:
            bar.close()
    return done


def _pin(shares) -> None:
    """A worker's start: its cores, before jax makes its thread pool (sized by the cores it may use), and the
    compile cache, so a worker loads the programs an earlier run compiled instead of compiling them again."""
    os.sched_setaffinity(0, shares.get())
    from ffjax import compile_cache

    compile_cache.enable()


def _train_and_evaluate(job: Job, init, force: bool) -> tuple[float, float]:
    """In a worker: train() and evaluate() one job; their wall seconds."""
    t = time.perf_counter()
    folder = job.folder()
    train(job.cfg, job.spec, job.seed, job.data_root, folder, (lambda: init) if init is not None else None,
          force, progress=False)
    train_s = round(time.perf_counter() - t, 1)
    t = time.perf_counter()
    evaluate(job.cfg, folder, job.data_root, force)
    return train_s, round(time.perf_counter() - t, 1)
