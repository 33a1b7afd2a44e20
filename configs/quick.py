"""`quick`: the README's main command; every table end to end on a 2-core CPU, with trained models.

Scale note: 48x64 renders padded to 64x64, a ViT of dim 64 / depth 2 / patch 8, a ResNet with the
torchvision stem (stride 4), 6,000 training presses, 15 epochs (1,395 steps). Sized for a 2-core CPU by the
same budget rule for every method: the same data, batch and number of steps, and each backbone the smallest
of its family whose jitted train step is about as cheap as the other's there (a larger ViT, or the ResNet's
stride-1 stem, costs several times more per step). The measured step times are in docs/benchmarks.md, and
the measured time of the whole command in docs/results/quick/README.md. It shows the paper's effects at toy
scale; it does not reproduce its absolute numbers.

Its values are the defaults of configs/base.py, so it changes nothing.
"""

from configs.base import CONFIG as _BASE
from configs.checks import derive

CONFIG = derive(_BASE, {})
