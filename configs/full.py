"""`full`: quick's model, data and schedule with three seeds and test sets twice as large, for a 2-core CPU.

Why not longer training: on a 2-core CPU the budget goes to the seeds (the spread every table reports) and
to larger test sets (tighter means), which is what `full` is for; longer DINO pretraining would cost the
ResNet most (its pretraining step is the slowest; measured times in docs/training.md).
"""

from configs.checks import derive
from configs.quick import CONFIG as _QUICK

CONFIG = derive(_QUICK, {"seeds": 3, "data": {"unseen_per_object": 200, "sensor_test_per_indenter": 60}})
