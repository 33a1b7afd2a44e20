"""`full`: the CPU-scale reproduction; more data, longer training, several seeds; ~1 h on 2 cores."""

import copy

from configs.quick import CONFIG as _QUICK

CONFIG = copy.deepcopy(_QUICK)
CONFIG["data"].update(train_per_indenter=800, val_per_indenter=100, unseen_per_object=200,
                      sensor_test_per_indenter=60)
CONFIG["train"].update(epochs=5)
CONFIG["pretrain"].update(steps=600, corpus_size=12000, warmup_steps=40, teacher_temp_warmup=150)  # ~8 min/backbone
