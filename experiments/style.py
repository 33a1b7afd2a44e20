"""One look per method in every figure and notebook: a fixed colour and marker (never assigned by position, so
DINO R is the same colour in Table I, the sweep, stability and the speed chart), the name people read, and the
glyph that marks the paper's numbers (a star: nothing an error bar or its cap can be mistaken for)."""

from __future__ import annotations

import zlib

from ffjax import registry

# colour-blind-safe (Okabe-Ito), one per registry method; a method added later gets a stable colour from its name
_STYLE = {
    "resnet_rd": ("#E69F00", "s"),
    "dino_f_r": ("#56B4E9", "v"),
    "dino_f_rd": ("#0072B2", "^"),
    "dino_r": ("#009E73", "D"),
    "dino_rd": ("#D55E00", "o"),
    "dino_rd_scratch": ("#CC79A7", "P"),
}
_SPARE = ("#999999", "#F0E442", "#000000", "#882255", "#44AA99", "#117733")
PAPER = {"marker": "*", "s": 110, "color": "black", "edgecolors": "white", "linewidths": 0.6, "zorder": 5}
PAPER_LABEL = "paper (real sensor)"


def colour(method: str) -> str:
    """The method's colour, the same in every figure."""
    if method in _STYLE:
        return _STYLE[method][0]
    return _SPARE[zlib.crc32(method.encode()) % len(_SPARE)]


def marker(method: str) -> str:
    return _STYLE.get(method, (None, "X"))[1]


def name(method: str) -> str:
    """The name people read (the paper's: "DINO RD"); a name the registry does not know is shown as given."""
    try:
        return registry.get(method).paper_name
    except KeyError:
        return method
