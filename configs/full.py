"""`full`: quick's model, data and schedule with three seeds and test sets twice as large; ~1 h on 2 cores.

Why not longer training: on a 2-core CPU one seed of the five methods trains in ~13 min at quick (the
ResNet is half of it), and DINO pretraining costs ~3 s per ResNet step (quick: 537 s for 180 steps), so
600 steps would add ~30 min for the ResNet alone. The hour goes to the seeds (the spread every table
reports) and to larger test sets (tighter means), which is what `full` is for.
"""

from configs.checks import derive
from configs.quick import CONFIG as _QUICK

CONFIG = derive(_QUICK, {"seeds": 3, "data": {"unseen_per_object": 200, "sensor_test_per_indenter": 60}})
