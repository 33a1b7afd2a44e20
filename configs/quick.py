"""`quick`: the README's main command; every table end to end on a 2-core CPU in < 30 min, trained models.

Scale note: 48x64 renders padded to 64x64, a ViT of dim 64 / depth 2 / patch 8, a ResNet with the
torchvision stem (stride 4), 6,000 training presses, 15 epochs (1,395 steps). Sized from measurements on
the 2-core CPU (jitted step, batch 64): ViT 128/4 + decoder 750 ms, ViT 64/2 + the (32,16,16,8) decoder
170 ms; ResNet with the stride-1 stem 3.0 s, with the torchvision stem 240 ms. The same budget rule for
every method: the same data, batch and number of steps; each backbone the smallest of its family whose
step costs ~200 ms here. It shows the paper's effects at toy scale; it does not reproduce its absolute
numbers.

Its values are the defaults of configs/base.py, so it changes nothing.
"""

from configs.base import CONFIG as _BASE
from configs.checks import derive

CONFIG = derive(_BASE, {})
