"""A stand-in for the few Open3D calls roodi-toolkit makes, for the GPU machine of ``benchmarks/gpu/run.sh`` only.

That machine reaches no package index, and what travels to it is limited to 64 MiB: Open3D's wheel (95 MB for
``open3d-cpu``) cannot be carried there. The extraction's prune asks Open3D for exact k nearest neighbours and
radius searches over the Gaussian centres; this module answers the same questions with scipy's ``cKDTree`` (also
exact, so the neighbours are the same up to ties). It is never installed and never on the path of a user's run; the
toolkit itself depends on the real Open3D.
"""

from __future__ import annotations

import types

import numpy as np
from scipy.spatial import cKDTree

int32 = np.int32
int64 = np.int64


class Tensor:
    def __init__(self, array: np.ndarray) -> None:
        self._array = np.asarray(array)

    @staticmethod
    def from_numpy(array: np.ndarray) -> "Tensor":
        return Tensor(array)

    def numpy(self) -> np.ndarray:
        return self._array


class NearestNeighborSearch:
    def __init__(self, points: Tensor, index_dtype=np.int32) -> None:
        self._points = np.asarray(points.numpy(), dtype=np.float64)
        self._dtype = index_dtype
        self._tree = None

    def knn_index(self) -> bool:
        self._tree = cKDTree(self._points)
        return True

    def knn_search(self, queries: Tensor, knn: int):
        d, i = self._tree.query(np.asarray(queries.numpy(), np.float64), k=int(knn), workers=-1)
        d = np.asarray(d).reshape(len(queries.numpy()), int(knn))
        i = np.asarray(i).reshape(len(queries.numpy()), int(knn))
        return Tensor(i.astype(self._dtype)), Tensor((d * d).astype(np.float32))


core = types.SimpleNamespace(Tensor=Tensor, int32=np.int32, int64=np.int64,
                             nns=types.SimpleNamespace(NearestNeighborSearch=NearestNeighborSearch))


class PointCloud:
    def __init__(self, points) -> None:
        self.points = np.asarray(points, dtype=np.float64)


class KDTreeFlann:
    def __init__(self, cloud: PointCloud) -> None:
        self._tree = cKDTree(cloud.points)

    def search_radius_vector_3d(self, query, radius: float):
        idx = sorted(self._tree.query_ball_point(np.asarray(query, np.float64), float(radius)))
        return len(idx), idx, None


geometry = types.SimpleNamespace(PointCloud=PointCloud, KDTreeFlann=KDTreeFlann)
utility = types.SimpleNamespace(Vector3dVector=lambda a: np.asarray(a, np.float64),
                                random=types.SimpleNamespace(seed=lambda s: None))
__version__ = "stand-in"
