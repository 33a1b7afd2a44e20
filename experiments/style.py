"""One look for every figure: a fixed colour and marker per method (never assigned by position, so DINO R is the
same colour in Table I, the sweep, stability and the speed chart), the name people read, how the paper's numbers
are drawn (a hollow hatched bar in the method's colour beside ours), and the shared machinery: fonts (RC, applied
by @plots), figures outside pyplot (figure), axis labels and the save (save)."""

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


# ---- the shared figure machinery: every figure of experiments/ is drawn with these ----------------------------
# Figures are built on matplotlib's object API (matplotlib.figure.Figure on an Agg canvas), never through pyplot's
# global backend: saving works headless, and a notebook's `%matplotlib inline` (or any backend a user chose) is
# left as it was. Sizes and fonts come from RC, applied only while a @plots function draws.

DPI = 120  # every PNG: small enough to commit, sharp enough to read
RC = {"font.size": 9, "axes.titlesize": 10, "axes.labelsize": 9, "xtick.labelsize": 8, "ytick.labelsize": 8,
      "legend.fontsize": 8, "legend.title_fontsize": 8, "figure.titlesize": 11, "figure.dpi": DPI,
      "savefig.dpi": DPI, "hatch.linewidth": 0.8, "axes.axisbelow": True, "grid.alpha": 0.3}
ERROR = "normalized L1 error (%)"  # the y label of every force-error axis
PAPER_HATCH = "////"
# the paper's value as a bar: hollow, hatched and edged in its method's colour, beside ours (never on it)
PAPER_BAR = {"facecolor": "white", "linewidth": 1.0, "hatch": PAPER_HATCH}
OURS_LABEL = "ours (simulated)"
CLIPPED_LABEL = "\u2191 n: a paper value above the axis (bar clipped)"
PAPER_ROOM = 1.5  # a paper value above this many times our highest point is clipped (drawn at the edge, value written)


def plots(fn):
    """Decorator for a function that draws figures: it runs inside `matplotlib.rc_context(RC)` (restored after,
    whatever it raises), so every figure has the same fonts and nothing global changes."""
    import functools

    @functools.wraps(fn)
    def drawn(*args, **kwargs):
        import matplotlib

        with matplotlib.rc_context(RC):
            return fn(*args, **kwargs)

    drawn.styled = True  # tests: every plotting function is drawn through here
    return drawn


def figure(nrows: int = 1, ncols: int = 1, figsize=(8.0, 4.0), layout=None, **subplots_kw):
    """(fig, axes): a Figure on its own Agg canvas, outside pyplot (no backend is chosen or switched, nothing for
    pyplot to close). nrows = 0: the figure alone (axes None), for a caller that lays out its own."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig, (fig.subplots(nrows, ncols, **subplots_kw) if nrows else None)


def error_axis(ax, what: str | None = None, axis: str = "y") -> None:
    """Label a force-error axis the same everywhere: 'normalized L1 error (%)', or '<what> normalized L1 error (%)'
    (e.g. what="validation")."""
    text = f"{what} {ERROR}" if what else ERROR
    (ax.set_ylabel if axis == "y" else ax.set_xlabel)(text)


def save(fig, path, then=None, bottom: float = 0.0, dpi: int = DPI):
    """Lay out, write atomically (tmp + rename) at `dpi`, release. A figure with a layout engine of its own
    (layout="constrained") keeps it; any other gets tight_layout with its axes kept below the figure's title.
    then: called with no arguments once the layout is final, before the write (e.g. common.label_points, which
    places labels in display space). bottom: a strip kept free below the axes (figure fraction), e.g. for the
    provenance footer. A pyplot figure (a diagnostic's) is closed in pyplot after; ours never were in it."""
    from pathlib import Path

    path = Path(path)
    if fig.get_layout_engine() is None:
        fig.tight_layout(rect=(0, bottom, 1, 1))
        title = _suptitle(fig)  # on a tall grid tight_layout can put the top row's titles under the figure's title
        if title is not None:
            renderer = fig.canvas.get_renderer()
            below = title.get_window_extent(renderer).y0 / fig.bbox.height
            axes = [ax for ax in fig.axes if ax.get_visible()]
            top = max((ax.get_tightbbox(renderer).y1 / fig.bbox.height for ax in axes), default=0.0)
            if top > below - 0.005:
                fig.tight_layout(rect=(0, bottom, 1, below - 0.01))
    else:
        fig.draw_without_rendering()  # the engine's layout, final before `then` reads positions
    if then is not None:
        then()
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp, dpi=dpi)
    if getattr(fig.canvas, "manager", None) is not None:  # made through pyplot: leave none of it behind
        import matplotlib.pyplot as plt

        plt.close(fig)
    tmp.replace(path)
    return path


def _suptitle(fig):
    """The figure title's Text artist, None when there is none (`fig.get_suptitle()` gives its string; the artist
    is the last of `fig.texts` with that text: suptitle reuses its artist)."""
    text = fig.get_suptitle()
    return next((t for t in reversed(fig.texts) if t.get_text() == text), None) if text else None


def paper_top(ours_high: float, paper_values, room: float = PAPER_ROOM) -> float:
    """The top of a bar chart's y axis: our highest point (error bar included) with some headroom, raised to a
    paper value only where that is within `room` times ours (a far higher one would squash our bars: it is drawn
    clipped at the top, see paper_bars)."""
    import numpy as np

    vals = [float(v) for v in paper_values if np.isfinite(v)]
    near = [v for v in vals if v <= room * ours_high]
    return 1.1 * max([ours_high, *near])


def paper_bars(ax, x, values, width: float, method: str, top: float | None = None) -> int:
    """The paper's values for one method as hollow hatched bars in its colour, at x (beside our bars, which they
    cannot hide). A value above `top` (the axis' top, paper_top) is drawn up to it, clipped, with its number
    written at the edge after an up-arrow (CLIPPED_LABEL says so in a legend). Returns how many were clipped."""
    import numpy as np

    c = colour(method)
    v = np.asarray(values, float)
    x = np.asarray(x, float)
    clip = np.isfinite(v) & (v > top) if top is not None else np.zeros(v.shape, bool)
    ax.bar(x, np.where(clip, top if top is not None else 0.0, v), width, edgecolor=c, zorder=2, **PAPER_BAR)
    for xi, vi in zip(x[clip], v[clip]):
        ax.annotate(f"\u2191{vi:.1f}", (xi, top), xytext=(0, -2), textcoords="offset points", ha="center",
                    va="top", fontsize=7, color=c, zorder=6,
                    bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none"})
    return int(clip.sum())


def bar_key(ours: str) -> list:
    """Legend handles that say which bar is which, in neutral grey (the methods' colours have their own entries):
    ours (filled; `ours` says what it is, e.g. 'mean ± std over 3 seeds') and the paper's (hollow, hatched)."""
    from matplotlib.patches import Patch

    return [Patch(facecolor="0.45", label=f"{OURS_LABEL}: {ours}"),
            Patch(edgecolor="0.45", label=PAPER_LABEL, **PAPER_BAR)]


def clipped_key() -> list:
    """The legend entry that explains a clipped paper bar (paper_bars): text only."""
    from matplotlib.lines import Line2D

    return [Line2D([], [], ls="none", label=CLIPPED_LABEL)]


def method_key(methods, labels: dict | None = None) -> list:
    """One legend handle per method: its colour (and `labels[m]` in place of its name where given)."""
    from matplotlib.patches import Patch

    return [Patch(facecolor=colour(m), label=(labels or {}).get(m, name(m))) for m in methods]
