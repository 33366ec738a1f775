"""The minimum-error boundary cut (image quilting's dynamic programme)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from bench.tiles import min_cut_python
from forest.bark.quilting import cut_mask, is_connected, min_cut_paths, path_cost, squared_error


def brute_force(err: np.ndarray) -> tuple[int, list[tuple[int, ...]]]:
    """Least cost over every connected top-to-bottom path, and all paths that reach it."""
    h, w = err.shape
    best, argbest = None, []
    for path in itertools.product(range(w), repeat=h):
        if any(abs(a - b) > 1 for a, b in itertools.pairwise(path)):
            continue
        cost = int(sum(err[i, j] for i, j in enumerate(path)))
        if best is None or cost < best:
            best, argbest = cost, [path]
        elif cost == best:
            argbest.append(path)
    assert best is not None
    return best, argbest


# small values make ties common, so the tie rules are exercised as well
SMALL_ERRORS = st.tuples(st.integers(1, 6), st.integers(1, 5)).flatmap(
    lambda hw: arrays(np.int64, hw, elements=st.integers(0, 4))
)
WIDE_ERRORS = st.tuples(st.integers(1, 6), st.integers(1, 5)).flatmap(
    lambda hw: arrays(np.int64, hw, elements=st.integers(0, 195075))
)


@settings(max_examples=300, deadline=None)
@given(err=st.one_of(SMALL_ERRORS, WIDE_ERRORS))
def test_cut_equals_brute_force(err: np.ndarray) -> None:
    path = min_cut_paths(err)
    assert path.shape == (err.shape[0],) and path.dtype == np.int64
    assert is_connected(path, err.shape[1])
    best, argbest = brute_force(err)
    assert int(path_cost(err, path)) == best
    assert tuple(path.tolist()) in argbest


@settings(max_examples=100, deadline=None)
@given(
    err=st.tuples(st.integers(1, 5), st.integers(1, 4), st.integers(1, 4)).flatmap(
        lambda shape: arrays(np.int64, shape, elements=st.integers(0, 3))
    )
)
def test_a_batch_is_each_band_on_its_own(err: np.ndarray) -> None:
    batched = min_cut_paths(err)
    assert batched.shape == err.shape[:2]
    for band, path in zip(err, batched, strict=True):
        assert np.array_equal(min_cut_paths(band), path)


@settings(max_examples=100, deadline=None)
@given(
    err=st.tuples(st.integers(1, 6), st.integers(1, 5)).flatmap(
        lambda hw: arrays(
            np.float64, hw, elements=st.floats(0, 1e3, allow_nan=False, allow_subnormal=False)
        )
    )
)
def test_float_errors_reach_the_brute_force_cost(err: np.ndarray) -> None:
    path = min_cut_paths(err)
    assert is_connected(path, err.shape[1])
    best, _ = brute_force_float(err)
    assert path_cost(err, path) == pytest.approx(best, rel=1e-12, abs=1e-9)


def brute_force_float(err: np.ndarray) -> tuple[float, None]:
    h, w = err.shape
    costs = [
        float(sum(err[i, j] for i, j in enumerate(p)))
        for p in itertools.product(range(w), repeat=h)
        if all(abs(a - b) <= 1 for a, b in itertools.pairwise(p))
    ]
    return min(costs), None


@settings(max_examples=100, deadline=None)
@given(err=st.one_of(SMALL_ERRORS, WIDE_ERRORS))
def test_plain_python_baseline_finds_the_same_cut(err: np.ndarray) -> None:
    assert min_cut_python(err.tolist()) == min_cut_paths(err).tolist()


def test_large_band_matches_baseline_and_stays_connected() -> None:
    rng = np.random.default_rng(5)
    err = rng.integers(0, 3 * 255**2, (8, 256, 32))
    paths = min_cut_paths(err)
    assert is_connected(paths, 32).all()
    for band, path in zip(err, paths, strict=True):
        assert min_cut_python(band.tolist()) == path.tolist()


def test_cut_follows_a_zero_error_valley() -> None:
    err = np.full((6, 7), 9)
    valley = [3, 4, 5, 5, 4, 3]
    err[np.arange(6), valley] = 0
    assert min_cut_paths(err).tolist() == valley
    assert min_cut_paths(np.zeros((4, 3))).tolist() == [0, 0, 0, 0]  # ties: lowest, straight


def test_squared_error_is_exact_for_8_and_16_bit() -> None:
    a = np.array([[[255, 0, 255]]], np.uint8)
    b = np.array([[[0, 255, 0]]], np.uint8)
    e8 = squared_error(a, b)
    assert e8.dtype == np.int32 and int(e8[0, 0]) == 3 * 255**2
    e16 = squared_error(a.astype(np.uint16) * 257, b.astype(np.uint16) * 257)
    assert e16.dtype == np.int64 and int(e16[0, 0]) == 3 * 65535**2
    with pytest.raises(ValueError, match="differ in shape"):
        squared_error(a, b[:, :, :2])


def test_cut_mask_and_bad_shapes() -> None:
    mask = cut_mask(np.array([0, 2, 3]), 3)
    assert mask.tolist() == [[False] * 3, [True, True, False], [True] * 3]
    assert not is_connected(np.array([0, 2]), 3)
    with pytest.raises(ValueError, match=r"\(\.\.\., h, w\)"):
        min_cut_paths(np.zeros(5))
    with pytest.raises(ValueError):
        min_cut_paths(np.zeros((3, 0)))
