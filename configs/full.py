"""`full`: the CPU-scale reproduction; more data, longer training, several seeds; ~1 h on 2 cores."""

import copy

from configs.quick import CONFIG as _QUICK

CONFIG = copy.deepcopy(_QUICK)
CONFIG["data"].update(train_per_indenter=1200, val_per_indenter=100, unseen_per_object=200,
                      sensor_test_per_indenter=60)
CONFIG["train"].update(epochs=8)
CONFIG["pretrain"].update(steps=2500, corpus_size=12000)
