"""The default prune's neighbour graph (pykdtree, Morton order), its two-pass pieces and the Morton permutation,
each against a slow reference: brute-force K-NN, SciPy's one-pass connected components, a stable argsort."""

from __future__ import annotations

import numpy as np
import pytest

from roodi_toolkit.errors import EnvironmentProblemError
from roodi_toolkit.prune.knn import _spread_bits, morton_order
from roodi_toolkit.prune import graph as graph_module
from roodi_toolkit.prune.graph import components, neighbour_graph
from roodi_toolkit.prune.scene import prune_cloud
from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud


def _brute_knn(pts: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the K nearest (excluding the row itself) by sorting every distance: ``[N, K]`` distances and the
    full ``[N, N]`` distance matrix (diagonal at inf)."""
    full = np.sqrt(np.sum((pts[:, None, :].astype(np.float64) - pts[None, :, :]) ** 2, axis=2))
    np.fill_diagonal(full, np.inf)
    return np.sort(full, axis=1)[:, :k], full


@pytest.mark.parametrize("k", [1, 5, 16])
def test_neighbour_graph_matches_brute_force(k):
    pts = np.random.default_rng(k).normal(size=(600, 3)).astype(np.float32)
    graph = neighbour_graph(pts, k)
    assert sorted(graph.order.tolist()) == list(range(len(pts)))
    ref, full = _brute_knn(pts, k)
    neighbors, dist = graph.to_input_order()
    assert neighbors.shape == dist.shape == (len(pts), k) and dist.dtype == np.float32
    assert not np.any(neighbors == np.arange(len(pts))[:, None])
    np.testing.assert_allclose(dist, ref, rtol=1e-6, atol=1e-7)  # float32 search: within a few ulp
    np.testing.assert_allclose(np.take_along_axis(full, neighbors, axis=1), ref, rtol=1e-6, atol=1e-7)
    # rows are Morton positions: the graph's own arrays agree with the input-order view
    np.testing.assert_array_equal(graph.order[graph.neighbors.astype(np.int64)], neighbors[graph.order])


def test_neighbour_graph_ties_and_duplicates():
    rng = np.random.default_rng(1)
    # a unit grid: many neighbours at exactly equal distances; plus groups of identical centres
    grid = np.stack(np.meshgrid(*[np.arange(6.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    copies = rng.integers(1, 7, size=len(grid))
    pts = np.repeat(grid, copies, axis=0).astype(np.float32)
    k = 4
    graph = neighbour_graph(pts, k)
    neighbors, dist = graph.to_input_order()
    ref, full = _brute_knn(pts, k)
    own = np.arange(len(pts))
    assert not np.any(neighbors == own[:, None])
    assert all(len(set(row)) == k for row in neighbors)  # no neighbour twice
    np.testing.assert_array_equal(dist, ref.astype(np.float32))  # ties: any of the tied neighbours, same distance
    np.testing.assert_array_equal(np.take_along_axis(full, neighbors, axis=1).astype(np.float32), dist)
    group = np.repeat(copies, copies)
    assert np.array_equal((dist == 0).sum(axis=1), np.minimum(group - 1, k))


def test_neighbour_graph_without_pykdtree_says_what_to_install(monkeypatch):
    monkeypatch.setattr(graph_module, "KDTree", None)  # its import failed, as if not installed
    with pytest.raises(EnvironmentProblemError, match="pip install pykdtree"):
        neighbour_graph(np.zeros((10, 3), dtype=np.float32), 3)


@pytest.mark.parametrize("k", [2, 4, 9, 16])
def test_components_in_two_passes_equal_scipys_one_pass(k):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(k)
    n = 3000
    # links mostly between nearby indices, a few across
    neighbors = (np.arange(n)[:, None] + rng.integers(-40, 41, size=(n, k))) % n
    across = rng.random((n, k)) < 0.02
    neighbors[across] = rng.integers(0, n, size=int(across.sum()))
    linked = rng.random((n, k)) < 1.2 / k  # about 1.2 links out per node: many pieces
    label, sizes = components(neighbors.astype(np.uint32), linked)
    rows = np.repeat(np.arange(n), k)[linked.ravel()]
    graph = coo_matrix((np.ones(len(rows)), (rows, neighbors.ravel()[linked.ravel()])), shape=(n, n))
    count, ref = connected_components(graph, directed=False)
    assert len(sizes) == count > 1 and sizes.sum() == n
    # the same partition: a one-to-one map between the two labellings
    pairs = np.unique(np.stack([label, ref], 1), axis=0)
    assert len(pairs) == count
    np.testing.assert_array_equal(np.sort(sizes), np.sort(np.bincount(ref)))


def test_union_find_on_long_chains_and_stars():
    """The hooking rounds end on the graphs that need the most of them: a path numbered against its direction, a
    path in random order, a star, and no links at all."""
    from roodi_toolkit.prune.graph import _union_find

    n = 5000
    rng = np.random.default_rng(0)
    path = np.arange(n)[::-1]
    shuffled = rng.permutation(n)
    for order in (path, shuffled):
        f = _union_find(order[:-1], order[1:], n)
        assert (f == 0).all()
    star = _union_find(np.full(n - 1, n - 1), np.arange(n - 1), n)
    assert (star == 0).all()
    two = _union_find(np.array([3, 1]), np.array([4, 2]), 6)
    assert two.tolist() == [0, 1, 1, 3, 3, 5]
    assert _union_find(np.zeros(0, int), np.zeros(0, int), 4).tolist() == [0, 1, 2, 3]


def test_object_mode_keeps_the_first_of_two_equal_pieces():
    a = planted_floater_cloud(FloaterMix("sphere", n_object=1500, far_fraction=0, near_fraction=0), 0).cloud
    b = a.with_fields(means=a.means + np.float32(10.0))  # the same piece, far away: equally large
    for first, second in ((a, b), (b, a)):
        both = type(a).concatenate([first, second])
        _, keep, report = prune_cloud(both, mode="object", max_piece=0)  # any detached piece goes
        assert report.mode == "object"
        assert keep[:len(a)].mean() > 0.99 and not keep[len(a):].any()  # pieces numbered in input order


def _stable_morton_reference(points: np.ndarray, bits: int) -> np.ndarray:
    """The Z-order permutation by a stable argsort of the interleaved cell codes (computed in float64)."""
    p = np.asarray(points, dtype=np.float64)
    lo = p.min(axis=0)
    span = float((p.max(axis=0) - lo).max())
    cells = ((p - lo) * ((2**bits - 1) / span)).astype(np.uint32)
    code = _spread_bits(cells[:, 0]) | (_spread_bits(cells[:, 1]) << np.uint32(1)) | (
        _spread_bits(cells[:, 2]) << np.uint32(2))
    return np.argsort(code, kind="stable")


@pytest.mark.parametrize("bits", [2, 6, 10])
def test_morton_order_equals_a_stable_argsort_of_the_codes(bits):
    rng = np.random.default_rng(bits)
    for pts in (rng.normal(size=(2000, 3)).astype(np.float32),
                rng.integers(0, 4, size=(2000, 3)).astype(np.float64)):  # many equal codes: input order kept
        np.testing.assert_array_equal(morton_order(pts, bits), _stable_morton_reference(pts, bits))


def test_neighbour_graph_with_centres_too_far_apart_for_float32_squares():
    pts = np.random.default_rng(3).normal(size=(40, 3)).astype(np.float32)
    pts[3] = 1e38  # its squared distances overflow float32: the search falls back to float64
    neighbors, dist = neighbour_graph(pts, 4).to_input_order()
    assert neighbors.max() < len(pts) and not np.any(neighbors == np.arange(len(pts))[:, None])
    ref, _ = _brute_knn(pts, 4)
    np.testing.assert_allclose(dist, ref, rtol=1e-6)
    assert np.all(dist[3] > 1e38)
