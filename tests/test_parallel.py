"""Block passes on threads: the same arrays on any number of threads."""

from __future__ import annotations

import numpy as np
import pytest

from forest.growth import expand, parallel
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.growth.wind import Wind


@pytest.mark.parametrize("preset", ["oak", "willow"])
def test_block_passes_equal_on_any_thread_count(
    preset: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    options = ForestOptions(
        trees=6, area=(60.0, 60.0), placement="grid", wind=Wind(strength_deg=8.0), frames=2
    )
    monkeypatch.setattr(expand, "BLOCK_PIECES", 512)  # several blocks of a few trees
    runs = []
    for threads in (1, 3):
        monkeypatch.setattr(parallel, "block_threads", lambda t=threads: t)
        f = generate_forest(load_preset(preset), 7, options)
        assert len(f.graph.blocks) >= 3  # several blocks, so the threads share them
        runs.append((f.transforms, f.palette(), f.palette(0.4)))
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_failing_block_raises_in_the_caller() -> None:
    def work(blocks: list[int]) -> None:
        if 2 in blocks:
            raise ValueError("block 2")

    with pytest.raises(ValueError, match="block 2"):
        parallel.for_block_groups(work, [0, 1, 2, 3])


def test_expand_in_groups_equals_one_expand(monkeypatch: pytest.MonkeyPatch) -> None:
    from forest.growth.compile import compile_grammar
    from forest.growth.keyed import GROW, tree_keys
    from forest.settings import get_settings

    cg = compile_grammar(load_preset("birch"))
    keys = tree_keys(5, np.arange(3 * parallel.MIN_TREES_PER_GROUP + 7), GROW)
    radius = np.linspace(0.2, 0.4, len(keys))
    one = expand.expand(cg, keys, get_settings(), radius)
    monkeypatch.setattr(parallel, "block_threads", lambda: 3)
    joined = parallel.expand_in_groups(cg, keys, get_settings(), radius)
    for name in one.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(one, name), getattr(joined, name), err_msg=name)
