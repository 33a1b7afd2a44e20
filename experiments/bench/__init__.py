"""The benchmarks: ffjax's speed against its PyTorch twins, FLOPs, scaling, the data path, the training loop.

`python -m experiments.bench` runs the suite (`suite.py`). Modules: `jax_step` (the jitted step, FLOP counts,
bf16), `torch_twin` (the PyTorch models, also runnable as a subprocess under another interpreter), `loop` (the
simulator, input pipeline and training loop against its own step), `dp` (data parallel, a subprocess),
`decoders` (the depth decoders' cost), `report` (report.md and plots).
"""
