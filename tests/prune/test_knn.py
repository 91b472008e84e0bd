"""Nearest neighbours: self excluded by index (duplicates kept), exact W2 neighbours against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.prune.knn import knn_centres, knn_w2, morton_order
from roodi_toolkit.prune.wasserstein import gaussian_shapes, w2_sq


def test_knn_matches_brute_force():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(700, 3)).astype(np.float32)
    nb, dist2 = knn_centres(pts, 8)
    full = np.sum((pts[:, None, :].astype(np.float64) - pts[None, :, :]) ** 2, axis=2)
    np.fill_diagonal(full, np.inf)
    ref = np.sort(full, axis=1)[:, :8]
    np.testing.assert_allclose(dist2, ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.take_along_axis(full, nb.astype(np.int64), axis=1), ref, rtol=1e-5, atol=1e-6)
    assert not np.any(nb == np.arange(len(pts))[:, None])


def test_duplicates_are_neighbours_at_zero_and_self_is_excluded_by_index():
    rng = np.random.default_rng(1)
    base = rng.normal(size=(60, 3)).astype(np.float32)
    copies = rng.integers(1, 9, size=60)  # groups of 1..8 identical centres; some larger than K + 1
    pts = np.repeat(base, copies, axis=0)
    k = 4
    nb, dist2 = knn_centres(pts, k)
    own = np.arange(len(pts))
    assert not np.any(nb == own[:, None])
    group_size = np.repeat(copies, copies)
    expected_zeros = np.minimum(group_size - 1, k)
    assert np.array_equal((dist2 == 0).sum(axis=1), expected_zeros)
    assert len(np.unique(nb, axis=1)) == len(pts)  # no row lists a neighbour twice
    assert all(len(set(row)) == k for row in nb)


def test_k_must_be_smaller_than_cloud():
    with pytest.raises(ConfigError, match="at least 6 Gaussians"):
        knn_centres(np.zeros((5, 3)), 5)


def test_morton_order_is_a_permutation():
    pts = np.random.default_rng(2).random((1000, 3))
    order = morton_order(pts)
    assert np.array_equal(np.sort(order), np.arange(1000))
    assert np.array_equal(morton_order(np.zeros((4, 3))), np.arange(4))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_w2_neighbours_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    n, k = 400, 6
    means = rng.normal(size=(n, 3)).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    ls = rng.normal(-2.5, 0.8, size=(n, 3)).astype(np.float32)
    ls[:20] += 2.5  # some oversized Gaussians whose W2 neighbours are far from their centre neighbours
    ls[20:30, 2] = -np.inf  # flat ones
    shapes = gaussian_shapes(quats, ls, np.float64)
    nb, best = knn_w2(means, shapes, k, first_candidates=k + 1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    full = w2_sq(means[i.ravel()], quats[i.ravel()], ls[i.ravel()], means[j.ravel()], quats[j.ravel()],
                 ls[j.ravel()]).reshape(n, n)
    np.fill_diagonal(full, np.inf)
    ref = np.sort(full, axis=1)[:, :k]
    np.testing.assert_allclose(best, ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.take_along_axis(full, nb.astype(np.int64), axis=1), ref, rtol=1e-9, atol=1e-12)
    # the centre-nearest neighbours are not the W2-nearest for the oversized ones: the mode matters
    centre_nb, _ = knn_centres(means, k)
    assert np.any(np.sort(centre_nb[:20], axis=1) != np.sort(nb[:20], axis=1))


def test_morton_codes_match_the_bit_by_bit_definition():
    """Bit b of axis a goes to bit 3b + a: the magic-number spreading agrees with the plain loop."""
    rng = np.random.default_rng(5)
    pts = rng.random((5000, 3))
    lo, span = pts.min(axis=0), float(np.ptp(pts, axis=0).max())
    cells = ((pts - lo) * (1023 / span)).astype(np.uint32)
    code = np.zeros(len(pts), dtype=np.uint32)
    for b in range(10):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint32(b)) & np.uint32(1)) << np.uint32(3 * b + axis)
    assert np.array_equal(morton_order(pts), np.argsort(code, kind="stable"))
