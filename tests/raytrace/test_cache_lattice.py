"""The radiance cache's lattice merge: samples are the distinct rows of (component, cell,
normal cell), numbered in lexicographic order. ``raytrace.cache._row_ids`` packs each row into
one integer and sorts that; NumPy's 2-d ``np.unique(axis=0)``, which compares rows field by
field, is the second method."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.cache import _row_ids


def _reference(key):
    return np.unique(key, axis=0, return_inverse=True)[1].ravel()


@pytest.mark.parametrize("seed", range(20))
def test_row_ids_equal_numpys_2d_unique(seed):
    rng = np.random.default_rng(seed)
    cols = int(rng.integers(1, 7))
    lo, hi = sorted(rng.integers(-50, 50, size=2))
    key = rng.integers(lo, hi + 1, size=(int(rng.integers(1, 2000)), cols))
    assert np.array_equal(_row_ids(key), _reference(key))


def test_row_ids_order_is_lexicographic_with_negative_cells():
    key = np.array([[1, -3, 0], [0, 5, 2], [1, -3, -1], [0, 5, 2], [0, -7, 9]])
    # sorted distinct rows: (0,-7,9) (0,5,2) (1,-3,-1) (1,-3,0)
    assert _row_ids(key).tolist() == [3, 1, 2, 1, 0]


def test_row_ids_ranges_too_wide_to_pack_fall_back():
    key = np.array([[0, 2**40, 0, 2**30], [1, -2**40, 5, 0], [0, 2**40, -1, 2**30], [0, 2**40, 0, 2**30]])
    assert np.array_equal(_row_ids(key), _reference(key))
    assert _row_ids(np.empty((0, 5), np.int64)).shape == (0,)
