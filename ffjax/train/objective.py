"""The training objective as data: loss = sum over TERMS of weight * term.

A `Term` is declared once: its name (the metric the step returns, the logs, validation and epochs.csv
carry), where its weight comes from (a field of the registry Method), and its error, a function of the
model's outputs and the batch giving one value per example. Everything downstream follows from TERMS, so a
new term is one entry here (and, if a Method sets its weight, that field in ffjax/registry.py).

    loss = alpha * L1(force) + beta * MSE(depth in [0, 1])   (the paper's objective)

The force L1 is in newtons averaged over axes; with train.force_loss="normalized" the optimized form weighs
each axis by 1 / its training range (state.force_weights), while the logged force_l1 stays plain newtons.
"""

from __future__ import annotations

import dataclasses
import functools
import operator
from collections.abc import Callable

import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class Term:
    """One loss term: `weight * batch mean of objective(state, out, batch)`, logged as `name`.

    weight: the Method field holding the term's weight (`default` for a spec without it).
    error: (state, out, batch) -> (B,) per-example error, logged (batch mean) as `name`.
    objective: the optimized per-example form when it differs from the logged one, (state, out, batch) -> (B,).
    needs: a model output the term reads; a model without it (or a zero weight) computes nothing and logs 0.
    train_column: epochs.csv has a train_<name> column (val_<name> is always there).
    """

    name: str
    weight: str
    error: Callable
    default: float = 0.0
    objective: Callable | None = None
    needs: str | None = None
    train_column: bool = True

    def weight_of(self, spec) -> float:
        return float(getattr(spec, self.weight, self.default))


def _force_abs(out, batch):
    return jnp.abs(out["force"] - batch["force"])


def force_l1(state, out, batch):
    """Mean |error| over the three axes, newtons."""
    return jnp.mean(_force_abs(out, batch), axis=-1)


def force_objective(state, out, batch):
    """force_l1, or with train.force_loss="normalized" each axis weighed by state.force_weights."""
    if state.force_weights is None:
        return force_l1(state, out, batch)
    return jnp.mean(_force_abs(out, batch) * jnp.asarray(state.force_weights), axis=-1)


def depth_mse(state, out, batch):
    """Mean squared error of the depth map (normalized to [0, 1])."""
    return jnp.mean(jnp.square(out["depth"] - batch["depth"]), axis=tuple(range(1, out["depth"].ndim)))


# The depth term has no train_ column: epochs.csv predates it and users' tools read its columns.
TERMS: tuple[Term, ...] = (
    Term("force_l1", "alpha", force_l1, default=1.0, objective=force_objective),
    Term("depth_mse", "beta", depth_mse, needs="depth", train_column=False),
)


@dataclasses.dataclass(frozen=True)
class Objective:
    """The terms a state trains with and their weights (hashable: a static field of TrainState).

    Only which terms are on (a non-zero weight) shapes the compiled step: the weights' values reach it as
    TrainState.loss_weights, an array, so a sweep over a weight compiles its step once, not once per value."""

    terms: tuple[Term, ...]
    weights: tuple[float, ...] = dataclasses.field(compare=False)
    active: tuple[bool, ...] = dataclasses.field(init=False)

    def __post_init__(self):
        object.__setattr__(self, "active", tuple(bool(w) for w in self.weights))

    @classmethod
    def of(cls, spec, terms: tuple[Term, ...] | None = None) -> Objective:
        """Weights from a Method's fields; the terms are TERMS unless given."""
        terms = TERMS if terms is None else tuple(terms)
        return cls(terms, tuple(t.weight_of(spec) for t in terms))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.terms)

    def losses(self, state, out, batch, mask=None):
        """(loss, {name: batch mean of its error}); `mask` (B,) weighs rows (a padded evaluation batch)."""
        if mask is None:
            reduce = jnp.mean
        else:
            n = jnp.maximum(jnp.sum(mask), 1.0)

            def reduce(x):
                return jnp.sum(x * mask) / n

        logged, optimized = {}, []
        for term, on, w in zip(self.terms, self.active, state.loss_weights):
            if term.needs is not None and not (on and term.needs in out):
                logged[term.name] = obj = reduce(jnp.zeros(out["force"].shape[:1], out["force"].dtype))
            else:
                logged[term.name] = reduce(term.error(state, out, batch))
                obj = logged[term.name] if term.objective is None else reduce(term.objective(state, out, batch))
            optimized.append(w * obj)
        return functools.reduce(operator.add, optimized), logged
