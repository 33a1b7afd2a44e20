"""Trained models on disk: one type, one reader and one writer for every form a user meets.

    trained = store.load("runs/x")          # a training run, a calibrated bundle or converted release weights
    model = trained.build()                 # the flax module; trained.variables are its weights
    trained.cfg, trained.spec, trained.stats, trained.input_size, trained.frame_size
    store.describe("runs/x")                # the same from model.json alone, no weights read
    store.save_bundle("out", trained)       # a self-contained copy (model.json + variables.msgpack)

Modules: `trained` (the type, the reader, bundles), `model_json` (what a model is: model.json, its digest, old
configs upgraded), `checkpoints` (a run's orbax checkpoints: resume, best, checksums), `packed` (the run state
as one buffer per dtype), `converted` (weights converted from PyTorch). Everything is verified on load and
every error names the file; a file that records no digest (written before ffjax recorded one) loads with an
UnverifiedWarning.
"""

from ffjax.store.checksums import UnverifiedWarning
from ffjax.store.model_json import MODEL_JSON
from ffjax.store.trained import BUNDLE_FORMAT, CHANNELS, RELEASE_STATS, Trained, describe, load, save_bundle

__all__ = ["BUNDLE_FORMAT", "CHANNELS", "MODEL_JSON", "RELEASE_STATS", "Trained", "UnverifiedWarning", "describe",
           "load", "save_bundle"]
