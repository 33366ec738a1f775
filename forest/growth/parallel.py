"""Independent groups of whole trees, processed on a few threads.

numpy releases the GIL inside its array loops, so the forward-kinematics passes (assembly,
palette) over different blocks run side by side; each thread takes every ``k``-th block and
keeps its own work arrays, and blocks write disjoint rows, so the result is the same on any
number of threads. A fresh pool per call: no thread outlives the call (a worker that forks a
job process never inherits a pool whose threads the child would lack).
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from forest.growth.expand import PieceGraph, check_forest_pieces, expand
from forest.growth.grammar import CompiledGrammar
from forest.settings import ForestSettings, get_settings

T = TypeVar("T")

MAX_AUTO_THREADS = 4  # beyond this, memory bandwidth, not cores, bounds these passes


def block_threads() -> int:
    """Threads for block passes: ``FOREST_THREADS``, or the usable cores (at most 4)."""
    wanted = get_settings().threads
    if wanted:
        return wanted
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(cores or 1, MAX_AUTO_THREADS))


def for_block_groups(work: Callable[[Sequence[T]], None], blocks: Sequence[T]) -> None:
    """``work(group)`` for every ``k``-th block of ``blocks`` on ``k`` threads (in this
    thread when one is enough); the first exception is raised here."""
    k = min(block_threads(), len(blocks))
    if k <= 1:
        work(blocks)
        return
    with ThreadPoolExecutor(k, thread_name_prefix="forest-blocks") as pool:
        for done in [pool.submit(work, blocks[i::k]) for i in range(k)]:
            done.result()


MIN_TREES_PER_GROUP = 64  # below this a thread's share is too small to pay for itself


def expand_in_groups(
    cg: CompiledGrammar,
    keys: NDArray[np.uint64],
    settings: ForestSettings,
    tree_radius: NDArray[np.float64],
    tree_size: NDArray[np.float64] | None = None,
) -> PieceGraph:
    """:func:`expand` of contiguous groups of trees on threads, joined in tree order: the
    same graph as one call (every draw is keyed on its tree and path, never on the trees
    beside it), with the forest's piece cap checked on the total."""
    k = min(block_threads(), len(keys) // MIN_TREES_PER_GROUP)
    if k <= 1:
        return expand(cg, keys, settings, tree_radius, tree_size)
    cuts = np.linspace(0, len(keys), k + 1).astype(int)
    with ThreadPoolExecutor(k, thread_name_prefix="forest-expand") as pool:
        parts = list(
            pool.map(
                lambda ab: expand(
                    cg,
                    keys[ab[0] : ab[1]],
                    settings,
                    tree_radius[ab[0] : ab[1]],
                    None if tree_size is None else tree_size[ab[0] : ab[1]],
                ),
                itertools.pairwise(cuts.tolist()),
            )
        )
    check_forest_pieces(sum(len(p) for p in parts), settings)
    return join_graphs(parts, cuts[:-1])


def join_graphs(parts: Sequence[PieceGraph], first_tree: NDArray[np.integer]) -> PieceGraph:
    """Graphs of consecutive tree ranges as one: tree and parent indices shifted."""
    first_piece = np.cumsum([0, *(len(p) for p in parts[:-1])])
    cols = {}
    for f in dataclasses.fields(PieceGraph):
        arrays = [getattr(p, f.name) for p in parts]
        if f.name == "tree":
            arrays = [a + np.int32(t) for a, t in zip(arrays, first_tree, strict=True)]
        elif f.name == "parent":
            arrays = [
                np.where(a >= 0, a + np.int32(o), a)
                for a, o in zip(arrays, first_piece, strict=True)
            ]
        cols[f.name] = np.concatenate(arrays)
    return PieceGraph(**cols)
