"""JSON turns tuples into lists; `retuple` gives them back (configs, model specs and converter metadata read
from disk must equal what was saved, and linen module fields must be hashable)."""

from __future__ import annotations

EVERY = object()  # retuple's `like` when every list is to become a tuple


def retuple(saved, like=EVERY):
    """`saved` with lists turned back into tuples where `like` (what was saved, e.g. the preset a config came
    from) has a tuple at the same place, or, with no `like`, every list (nested ones included)."""
    if like is EVERY:
        if isinstance(saved, dict):
            return {k: retuple(v) for k, v in saved.items()}
        return tuple(retuple(v) for v in saved) if isinstance(saved, list) else saved
    if isinstance(saved, dict) and isinstance(like, dict):
        return {k: retuple(v, like.get(k)) for k, v in saved.items()}
    if isinstance(saved, list) and isinstance(like, tuple):
        return tuple(saved)
    return saved
