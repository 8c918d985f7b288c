"""Covering arrays of strength t under constraints, built greedily one row at a time.

Each row starts from an uncovered t-tuple of the factor combination with the most still
uncovered, then takes, factor by factor, the value that completes the most uncovered tuples
(ties: the value in the most uncovered tuples overall), among the values that keep the row
extendable to a valid one: one row at a time as AETG and PICT build, without their random
choices, so one input gives one array. The constraints are a single vectorised predicate over
partial rows, so the tuples a constraint rules out are never asked for, and every row is valid
by construction.

We build our own because covertable's constraint engine, in pure Python, took 110 s for the
paper's 3-wise array and 98 s for a pairwise array of only two of the four richer obstacle slots.
"""

from __future__ import annotations

from itertools import combinations
from typing import Callable, Sequence

import numpy as np

UNSET = -1
# A partial row per line, UNSET where no value is chosen yet -> whether each extends to a valid row.
Extendable = Callable[[np.ndarray], np.ndarray]

_CHUNK_TUPLES = 1 << 18


def tuple_count(sizes: Sequence[int], strength: int) -> int:
    """How many t-tuples the factors have before constraints (the elementary symmetric polynomial)."""
    by_size = [1] + [0] * strength
    for size in sizes:
        for order in range(strength, 0, -1):
            by_size[order] += by_size[order - 1] * size
    return by_size[strength]


def valid_tuples(sizes: Sequence[int], factors: Sequence[int], extendable: Extendable) -> int:
    """How many value combinations of `factors` some valid row holds: every one needs its own row."""
    shape = [sizes[f] for f in factors]
    grid = np.indices(shape).reshape(len(factors), -1).T
    total = 0
    for start in range(0, len(grid), _CHUNK_TUPLES):
        partial = np.full((min(_CHUNK_TUPLES, len(grid) - start), len(sizes)), UNSET, dtype=np.int64)
        partial[:, list(factors)] = grid[start:start + _CHUNK_TUPLES]
        total += int(extendable(partial).sum())
    return total


class _Tuples:
    """Every t-tuple in one flat boolean array, combination by combination, each combination's
    tuples in mixed radix of its factors' value indices."""

    def __init__(self, sizes: np.ndarray, strength: int, extendable: Extendable):
        self.sizes = sizes
        self.combos = np.array(list(combinations(range(len(sizes)), strength)), dtype=np.int64)
        self.shapes = sizes[self.combos]
        self.strides = np.ones_like(self.shapes)
        for column in range(strength - 2, -1, -1):
            self.strides[:, column] = self.strides[:, column + 1] * self.shapes[:, column + 1]
        self.counts = self.strides[:, 0] * self.shapes[:, 0]
        self.offsets = np.concatenate(([0], np.cumsum(self.counts)[:-1]))
        self.combo_of = np.repeat(np.arange(len(self.combos), dtype=np.int32), self.counts)
        self.value_base = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        self.uncovered = self._valid(extendable)

    def _valid(self, extendable: Extendable) -> np.ndarray:
        valid = np.empty(int(self.counts.sum()), dtype=bool)
        start = 0
        while start < len(self.combos):
            stop = start + 1
            while stop < len(self.combos) and self.offsets[stop] - self.offsets[start] < _CHUNK_TUPLES:
                stop += 1
            partial = np.full((int(self.offsets[stop - 1] + self.counts[stop - 1] - self.offsets[start]), len(self.sizes)), UNSET, dtype=np.int64)
            row = 0
            for combo in range(start, stop):
                grid = np.indices(self.shapes[combo]).reshape(self.combos.shape[1], -1).T
                partial[row:row + len(grid), self.combos[combo]] = grid
                row += len(grid)
            valid[self.offsets[start]:self.offsets[start] + len(partial)] = extendable(partial)
            start = stop
        return valid

    def of_row(self, row: np.ndarray) -> np.ndarray:
        """The index of the tuple a full row holds in each combination."""
        return self.offsets + (row[self.combos] * self.strides).sum(axis=1)

    def values(self, indices: np.ndarray) -> np.ndarray:
        """(tuples, t): each tuple's (factor, value) as a flat value number (value_base + value)."""
        combo = self.combo_of[indices]
        digits = (indices - self.offsets[combo])[:, None] // self.strides[combo] % self.shapes[combo]
        return self.value_base[self.combos[combo]] + digits


class _RowBuilder:
    """Builds one row, keeping per (factor, value) how many uncovered tuples that choice completes."""

    def __init__(self, tuples: _Tuples, extendable: Extendable, weight: np.ndarray):
        self.tuples, self.extendable, self.weight = tuples, extendable, weight
        sizes = tuples.sizes
        self.widest = int(sizes.max())
        self.value_exists = np.arange(self.widest)[None, :] < sizes[:, None]
        self.combos_with = [np.flatnonzero((tuples.combos == f).any(axis=1)) for f in range(len(sizes))]

    def build(self, seed_combo: int) -> np.ndarray:
        t = self.tuples
        sizes = t.sizes
        self.row = np.full(len(sizes), UNSET, dtype=np.int64)
        self.assigned_in_combo = np.zeros(len(t.combos), dtype=np.int64)
        self.gains = np.zeros((len(sizes), self.widest), dtype=np.int64)
        first = t.offsets[seed_combo] + int(np.flatnonzero(t.uncovered[t.offsets[seed_combo]:t.offsets[seed_combo] + t.counts[seed_combo]])[0])
        for factor, value in zip(t.combos[seed_combo], (first - t.offsets[seed_combo]) // t.strides[seed_combo] % t.shapes[seed_combo]):
            self._assign(int(factor), int(value))
        while (self.row == UNSET).any():
            self._assign(*self._best_choice())
        return self.row

    def _best_choice(self) -> tuple[int, int]:
        free = np.flatnonzero(self.row == UNSET)
        factor, value = np.nonzero(self.value_exists[free])
        factor = free[factor]
        score = self.gains[factor, value] * (1 << 32) + self.weight[self.tuples.value_base[factor] + value]
        trial = np.repeat(self.row[None, :], len(factor), axis=0)
        trial[np.arange(len(factor)), factor] = value
        score = np.where(self.extendable(trial), score, -1)
        best = int(np.argmax(score))
        if score[best] < 0:
            raise ValueError("no value keeps the row valid: the constraints' predicate says a partial row extends when it does not")
        return int(factor[best]), int(value[best])

    def _assign(self, factor: int, value: int) -> None:
        """Set the value, and credit the one factor still open in each combination it completes but one."""
        t = self.tuples
        self.row[factor] = value
        combos = self.combos_with[factor]
        self.assigned_in_combo[combos] += 1
        ready = combos[self.assigned_in_combo[combos] == t.combos.shape[1] - 1]
        if not len(ready):
            return
        members = t.combos[ready]
        member_values = self.row[members]
        open_member = member_values == UNSET
        base = t.offsets[ready] + (np.where(open_member, 0, member_values) * t.strides[ready]).sum(axis=1)
        open_factor = members[open_member]
        indices = base[:, None] + np.arange(self.widest)[None, :] * t.strides[ready][open_member][:, None]
        exists = self.value_exists[open_factor]
        completes = t.uncovered[np.where(exists, indices, 0)] & exists
        self.gains += np.bincount((open_factor[:, None] * self.widest + np.arange(self.widest)).ravel(), weights=completes.ravel(),
                                  minlength=self.gains.size).astype(np.int64).reshape(self.gains.shape)


def covering_array(sizes: Sequence[int], strength: int, extendable: Extendable) -> np.ndarray:
    """(rows, factors) value indices: every t-tuple that some valid row holds is in a row, and every
    row is valid. Deterministic: the same input gives the same array."""
    sizes_array = np.asarray(sizes, dtype=np.int64)
    if not 1 <= strength <= len(sizes_array):
        raise ValueError(f"strength {strength} is not between 1 and the {len(sizes_array)} factors")
    tuples = _Tuples(sizes_array, strength, extendable)
    # Per (factor, value): the uncovered tuples that hold it (counted in chunks: a tuple's values take t words).
    weight = np.zeros(int(sizes_array.sum()), dtype=np.int64)
    for start in range(0, len(tuples.uncovered), _CHUNK_TUPLES):
        held = start + np.flatnonzero(tuples.uncovered[start:start + _CHUNK_TUPLES])
        weight += np.bincount(tuples.values(held).ravel(), minlength=len(weight))
    left = np.add.reduceat(tuples.uncovered, tuples.offsets).astype(np.int64)
    builder = _RowBuilder(tuples, extendable, weight)
    rows = []
    while left.any():
        row = builder.build(int(np.argmax(left))).copy()
        held = tuples.of_row(row)
        new = held[tuples.uncovered[held]]
        tuples.uncovered[new] = False
        np.subtract.at(weight, tuples.values(new).ravel(), 1)
        np.subtract.at(left, tuples.combo_of[new], 1)
        rows.append(row)
    return np.array(rows, dtype=np.int64).reshape(len(rows), len(sizes_array))

