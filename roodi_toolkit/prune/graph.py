"""The K-nearest-centre graph of a cloud and its connected pieces: what the local tests of :mod:`.scene` judge on.

One K-NN search (pykdtree, rows in Morton order so that the gathers over ``[N, K]`` hit the cache) gives every
Gaussian its neighbours; :func:`components` finds the pieces the tests' links make of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

try:
    from pykdtree.kdtree import KDTree
except ImportError:  # named with what to install when the prune needs it (neighbour_graph)
    KDTree = None

from ..errors import EnvironmentProblemError
from ..progress import ProgressFactory, null_progress
from .knn import _drop_self, check_k, morton_order

__all__ = ["NeighbourGraph", "neighbour_graph", "components", "FIRST_COLUMNS"]


@dataclass(frozen=True)
class NeighbourGraph:
    """The K nearest centres of every Gaussian, rows in Morton (Z-curve) order.

    The local tests run in this order and only their per-Gaussian results go back to the input order: a row's
    neighbours are then mostly nearby rows, so the gathers over ``[N, K]`` (sizes, scales, graph links) hit the cache.

    Attributes:
        order: ``[N]`` the input index of each row.
        neighbors: ``[N, K]`` rows (not input indices, uint32 or any integer type) of the K nearest centres,
            excluding the row itself (may be a view of a wider array).
        dist: ``[N, K]`` float32 their distances, ascending (may be a view of a wider array).
    """

    order: np.ndarray
    neighbors: np.ndarray
    dist: np.ndarray

    def to_input_order(self) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(neighbors, dist)`` ``[N, K]`` with rows and indices in the input order."""
        neighbors = np.empty(self.neighbors.shape, dtype=np.intp)
        dist = np.empty_like(self.dist)
        neighbors[self.order] = self.order[self.neighbors]
        dist[self.order] = self.dist
        return neighbors, dist


def neighbour_graph(means: np.ndarray, k: int, progress: ProgressFactory = null_progress) -> NeighbourGraph:
    """Return the K nearest centres of every Gaussian (excluding itself by index), rows in Morton order.

    pykdtree (a maintained C kd-tree with OpenMP queries) searches float32 centres, queried with its own points in
    Morton order so that nearby queries in a row touch the same tree nodes. This search is most of the prune; on the
    2-core machine, CPU seconds for the 17 nearest of 611k real centres (``benchmarks/RESULTS.md``, "Prune on real
    splats"): pykdtree float32 1.4-1.65, pykdtree float64 2.05-2.1, SciPy's cKDTree 2.3-2.8, Open3D's tensor
    search 2.2-2.3, Open3D's whole statistical outlier removal 1.4-1.5; importing Open3D alone takes 1.2 s.
    Against float64 distances rounded to float32, the float32 search gives distances within 2 ulp and, where
    neighbours are tied to within that, may list another of them (33 of the real biker's 152,746 rows): the
    prune's decisions on the real donut, biker and lego splats are the same (measured, same RESULTS section).

    Args:
        means: ``[N, 3]`` centres (searched as float32).
        k: neighbours per Gaussian, 1 <= k < N.
        progress: progress factory.
    """
    if KDTree is None:  # a dependency of the package; only a broken install lacks it
        raise EnvironmentProblemError("the default prune needs pykdtree (a dependency of roodi-toolkit); install it "
                                      "with `pip install pykdtree`")

    n = len(means)
    check_k(k, n)
    points = np.ascontiguousarray(means, dtype=np.float32)
    order = morton_order(points)
    data = np.ascontiguousarray(points[order])
    with progress(total=n, desc="nearest neighbours") as bar:
        # squared distances, rooted in place: pykdtree's own root writes a fresh [N, K + 1] array, and first
        # touching fresh memory costs about as much as a pass over it on this machine
        dist, idx = KDTree(data).query(data, k=k + 1, sqr_dists=True)
        if (idx[:, -1] >= n).any():
            # squared distances past float32's range (centres ~1e19 apart): pykdtree then reports no neighbour
            # (index 2^32 - 1), so search again in float64, where float32 centres cannot overflow
            data = data.astype(np.float64)
            dist, idx = KDTree(data).query(data, k=k + 1)
            dist = dist.astype(np.float32)
        else:
            np.sqrt(dist, out=dist)
        bar.update(n)
    # a query finds itself first unless another Gaussian shares its centre; only those rows need the general rule,
    # written back in place so that the distances stay a view (no copy of [N, K])
    rows = np.arange(n)
    other = np.flatnonzero(idx[:, 0] != rows)
    if other.size:
        fixed_idx, fixed_dist = _drop_self(idx[other], dist[other], rows[other])
        idx[other, 1:], dist[other, 1:] = fixed_idx, fixed_dist
    # both stay views of the search's output: on this machine first touching fresh memory costs about as much as a
    # pass over it, so an [N, K] copy (or an int64 one, 2x larger) is not free
    return NeighbourGraph(order, idx[:, 1:], dist[:, 1:])


FIRST_COLUMNS = 4
"""components: pieces are first found along the links to the 4 nearest neighbours, then joined by the remaining
links between different pieces: the same pieces as one pass over all links, for a third of the work (on 2M real
Gaussians, 32M links of which 11k join pieces of the first pass)."""


def _union_find(u: np.ndarray, v: np.ndarray, n: int) -> np.ndarray:
    """Return ``f [N]`` int32: for each node the smallest node of its connected piece along the links ``u[i] - v[i]``.

    Hooking with pointer jumping over whole arrays (as Shiloach-Vishkin's): each round hooks the larger root of
    every link that still joins two trees onto the smaller (one fancy assignment: of several offers to a root any
    one wins, 1.3x faster than ``minimum.at`` taking the smallest), then jumps every pointer to its root. ``f[x] <=
    x`` always and a hooked root strictly decreases, so the rounds end, and they end only when every link lies inside
    one tree: the trees are then the pieces, each rooted at its smallest node (a piece's smallest node can only point
    at itself). On the 2M real graph: 4 rounds and 25 pointer jumps for the first pass; faster than SciPy's
    ``connected_components`` (which transposes the graph) and without importing SciPy, whose import alone took
    0.22-0.27 CPU s (``benchmarks/RESULTS.md``, issue 33).
    """
    f = np.arange(n, dtype=np.int32)
    u = np.asarray(u, dtype=np.int32)
    v = np.asarray(v, dtype=np.int32)
    fu, fv = u, v  # every node is its own root at first
    while u.size:
        apart = fu != fv
        if not apart.any():
            break
        u, v, fu, fv = u[apart], v[apart], fu[apart], fv[apart]
        f[np.maximum(fu, fv)] = np.minimum(fu, fv)  # of several offers to one root, any one wins
        while True:  # pointer jumping until every node points at a root
            jumped = f[f]
            if np.array_equal(jumped, f):
                break
            f = jumped
        fu, fv = f[u], f[v]
    return f


def components(neighbors: np.ndarray, linked: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the piece id ``[N]`` of every node and the size of every piece ``[C]`` (undirected links i -> nb).

    Piece ids are in an unspecified order (see :data:`FIRST_COLUMNS` for the two passes).
    """
    n, k = neighbors.shape
    first = min(FIRST_COLUMNS, k)
    near = linked[:, :first]
    rows = np.broadcast_to(np.arange(n, dtype=np.int32)[:, None], near.shape)
    root = _union_find(rows[near], neighbors[:, :first][near], n)
    rest = neighbors[:, first:]
    other = root[rest]  # [N, K - first] the piece of each remaining neighbour
    r, c = np.nonzero((other != root[:, None]) & linked[:, first:])
    if r.size:
        root = _union_find(root[r], other[r, c], n)[root]
    is_root = root == np.arange(n, dtype=np.int32)
    label = (np.cumsum(is_root) - 1)[root]  # pieces numbered by their smallest node
    return label, np.bincount(label)
