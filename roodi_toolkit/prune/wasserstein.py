"""Squared 2-Wasserstein distance between 3D Gaussians, vectorised over pairs, without eigendecompositions or
matrix square roots.

For N(mu_i, S_i) and N(mu_j, S_j)::

    W2^2 = |mu_i - mu_j|^2 + tr(S_i) + tr(S_j) - 2 tr((S_j^1/2 S_i S_j^1/2)^1/2)

The last trace is t = e_1 + e_2 + e_3 with e_k the square roots of the eigenvalues lambda_k of S_i S_j. With the
invariants I1 = sum(lambda), I2 = sum over pairs of lambda_a lambda_b and p = sqrt(prod(lambda)), the elementary
symmetric functions of the e_k satisfy ``t^2 = I1 + 2 s2`` and ``s2^2 = I2 + 2 p t`` (s2 = e1 e2 + e2 e3 + e1 e3).
So t is the fixed point of ``F(t) = sqrt(I1 + 2 sqrt(I2 + 2 p t))``; F is increasing and concave with slope
``p / (t s2) <= 1/9`` at the fixed point (AM-GM), and Newton's method from the upper bound ``sqrt(3 I1)`` reaches
machine precision in three steps. This replaces the quartic in t with a well-conditioned 1D solve.

For Gaussians given as (rotation, scales) the invariants are computed without cancellation: with
S = R diag(s)^2 R^T, the eigenvalues of S_i S_j are the squared singular values of G = D_j Q D_i, where
Q = R_j^T R_i and D = diag(s). Hence, with P = Q * Q (entry-wise squares of the relative rotation):

    I1 = |G|_F^2        = sum_ab s_ja^2 P_ab s_ib^2
    I2 = |cof(G)|_F^2   = sum_ab c_ja   P_ab c_ib      (c_a = product of the other two squared scales)
    p  = |det G|        = prod(s_j) prod(s_i)

Every term is a product of non-negative numbers, so the invariants carry only rounding error, flat (zero-scale)
Gaussians included. Each Gaussian's squared scales are divided by their sum (its trace) first, so the solve works
on numbers in [0, 1] (no underflow of I2 ~ s^8 in float32) and t is rescaled by sqrt(tr_i tr_j).

Error bound (tested): with u the unit round-off of the compute dtype, the result differs from the exact W2^2 of the
same parameters by at most ``c * u * (|mu_i - mu_j|^2 + tr(S_i) + tr(S_j))`` with c = 16 (measured worst case about 5 against a
40-digit reference, for float64 and float32 alike), i.e. 1.8e-15 relative for float64 (u = 2^-53) and 9.5e-7 for
float32 (u = 2^-24); float32 includes rounding the parameters to float32. The
cancellation in ``tr S_i + tr S_j - 2 t`` is inherent to the formula; the covariance term is clamped at zero, so the
result is never below ``|mu_i - mu_j|^2``.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..errors import CloudError
from ..progress import ProgressFactory, null_progress

NEWTON_STEPS = 3
"""Newton steps of the trace solve; 3 reach float64 round-off from the upper-bound start (measured)."""

NEWTON_STEPS_FLOAT32 = 2
"""Newton steps in float32: 2 already reach its round-off (max error 8u on 200k random, flat and near-isotropic
pairs, the same as 3 steps; 1 step leaves 62u)."""

W2_ERROR_FACTOR = 16.0
"""c in the documented error bound c * u * (|mu_i - mu_j|^2 + tr S_i + tr S_j)."""


def sum_sqrt_eigenvalues(i1: np.ndarray, i2: np.ndarray, p: np.ndarray, *,
                         steps: int = NEWTON_STEPS) -> np.ndarray:
    """Return t = sum of the square roots of the eigenvalues of a 3x3 PSD matrix from its invariants.

    Args:
        i1: ``[M]`` trace (sum of eigenvalues), >= 0.
        i2: ``[M]`` second invariant (sum of pairwise eigenvalue products), >= 0.
        p: ``[M]`` square root of the determinant, >= 0.
        steps: Newton steps on ``F(t) - t`` from the upper bound ``F(sqrt(3 i1))``.

    Example:
        >>> lam = np.array([4.0, 9.0, 16.0])  # square roots 2, 3, 4
        >>> float(sum_sqrt_eigenvalues(lam.sum(), lam[0] * lam[1] + lam[1] * lam[2] + lam[0] * lam[2],
        ...                            np.sqrt(lam.prod())))
        9.0
    """
    i1 = np.maximum(i1, 0)
    i2 = np.maximum(i2, 0)
    p = np.maximum(p, 0)
    two_p = p + p
    t = np.sqrt(i1 + 2 * np.sqrt(i2 + two_p * np.sqrt(3 * i1)))
    for _ in range(steps):
        s2 = np.sqrt(i2 + two_p * t)
        f = np.sqrt(i1 + s2 + s2)
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = p / (f * s2)
        slope = np.where(s2 > 0, slope, 0)  # rank <= 1 (s2 = 0) implies p = 0: F is flat
        t = t + (f - t) / (1 - slope)
    return t


@dataclass(frozen=True)
class GaussianShapes:
    """Per-Gaussian quantities the pairwise W2 needs, precomputed once per cloud.

    Attributes:
        quats: ``[N, 4]`` unit quaternions w,x,y,z (zero quaternions become the identity).
        sq: ``[N, 3]`` squared scales divided by their sum (the trace).
        cof: ``[N, 3]`` products of the other two normalised squared scales.
        det_sqrt: ``[N]`` product of the normalised scales, sqrt(prod(sq)).
        trace: ``[N]`` tr(S) = sum of squared scales (not normalised).
    """

    quats: np.ndarray
    sq: np.ndarray
    cof: np.ndarray
    det_sqrt: np.ndarray
    trace: np.ndarray

    def __len__(self) -> int:
        return int(self.trace.shape[0])

    def take(self, index: np.ndarray) -> "GaussianShapes":
        """Return the shapes of the Gaussians at ``index`` (any integer array shape)."""
        return GaussianShapes(self.quats[index], self.sq[index], self.cof[index], self.det_sqrt[index],
                              self.trace[index])


def gaussian_shapes(quats_wxyz: np.ndarray, log_scales: np.ndarray, dtype: type = np.float64) -> GaussianShapes:
    """Return the per-Gaussian W2 quantities of rotations ``[N, 4]`` (w,x,y,z) and log-scales ``[N, 3]``.

    Computed in float64 and stored in ``dtype``. A Gaussian with all scales zero gets sq = cof = 0 and trace 0.
    """
    q = np.asarray(quats_wxyz, dtype=np.float64).reshape(-1, 4)
    ls = np.asarray(log_scales, dtype=np.float64).reshape(-1, 3)
    if q.shape[0] != ls.shape[0]:
        raise CloudError(f"quats_wxyz {list(q.shape)} and log_scales {list(ls.shape)} differ in length")
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    # Shift the log-scales by their max so exp never overflows or underflows as a whole triple.
    finite_max = np.max(np.where(np.isfinite(ls), ls, -np.inf), axis=1, keepdims=True)
    shift = np.where(np.isfinite(finite_max), finite_max, 0.0)
    rel = np.exp(2.0 * (ls - shift))  # squared scales / max squared scale, in [0, 1]
    rel_sum = rel.sum(axis=1, keepdims=True)
    safe = np.where(rel_sum > 0, rel_sum, 1.0)
    sq = rel / safe
    cof = np.stack([sq[:, 1] * sq[:, 2], sq[:, 0] * sq[:, 2], sq[:, 0] * sq[:, 1]], axis=1)
    det_sqrt = np.sqrt(sq[:, 0] * sq[:, 1] * sq[:, 2])
    with np.errstate(over="ignore"):
        trace = rel_sum[:, 0] * np.exp(2.0 * shift[:, 0])
    trace = np.where(rel_sum[:, 0] > 0, trace, 0.0)
    with np.errstate(over="ignore"):  # a trace past float32 (log scales of 80) is infinite in float32
        return GaussianShapes(q.astype(dtype), sq.astype(dtype), cof.astype(dtype), det_sqrt.astype(dtype),
                              trace.astype(dtype))


def _bures_sq(a: GaussianShapes, b: GaussianShapes) -> np.ndarray:
    """Return tr S_a + tr S_b - 2 tr((S_b^1/2 S_a S_b^1/2)^1/2), clamped at 0, for broadcastable shape arrays."""
    qa, qb = a.quats, b.quats
    aw, ax, ay, az = qa[..., 0], qa[..., 1], qa[..., 2], qa[..., 3]
    bw, bx, by, bz = qb[..., 0], -qb[..., 1], -qb[..., 2], -qb[..., 3]  # conj(q_b)
    # r = conj(q_b) * q_a, so R(r) = R_b^T R_a
    w = bw * aw - bx * ax - by * ay - bz * az
    x = bw * ax + bx * aw + by * az - bz * ay
    y = bw * ay - bx * az + by * aw + bz * ax
    z = bw * az + bx * ay - by * ax + bz * aw
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    # Q unnormalised-safe: r is a product of unit quaternions, so |r| = 1 up to rounding.
    q00 = 1 - 2 * (yy + zz)
    q01 = 2 * (xy - wz)
    q02 = 2 * (xz + wy)
    q10 = 2 * (xy + wz)
    q11 = 1 - 2 * (xx + zz)
    q12 = 2 * (yz - wx)
    q20 = 2 * (xz - wy)
    q21 = 2 * (yz + wx)
    q22 = 1 - 2 * (xx + yy)
    p00, p01, p02 = q00 * q00, q01 * q01, q02 * q02
    p10, p11, p12 = q10 * q10, q11 * q11, q12 * q12
    p20, p21, p22 = q20 * q20, q21 * q21, q22 * q22

    def quad(u: np.ndarray, v: np.ndarray) -> np.ndarray:  # sum_ab u_b P_ab v_a, P indexed [b-axis, a-axis]
        v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
        return (u[..., 0] * (p00 * v0 + p01 * v1 + p02 * v2)
                + u[..., 1] * (p10 * v0 + p11 * v1 + p12 * v2)
                + u[..., 2] * (p20 * v0 + p21 * v1 + p22 * v2))

    i1 = quad(b.sq, a.sq)
    i2 = quad(b.cof, a.cof)
    steps = NEWTON_STEPS_FLOAT32 if np.result_type(i1) == np.float32 else NEWTON_STEPS
    t = sum_sqrt_eigenvalues(i1, i2, a.det_sqrt * b.det_sqrt, steps=steps)
    ta, tb = a.trace, b.trace
    with np.errstate(over="ignore", invalid="ignore"):  # infinite traces give an infinite or NaN distance, silently
        bures = ta + tb - 2 * np.sqrt(ta * tb) * t
    return np.maximum(bures, 0)


def w2_sq_shapes(dist2: np.ndarray, a: GaussianShapes, b: GaussianShapes) -> np.ndarray:
    """Return W2^2 from squared centre distances and precomputed shapes (broadcastable), in the shapes' dtype."""
    return np.asarray(dist2, dtype=a.trace.dtype) + _bures_sq(a, b)


def w2_sq(means_a: np.ndarray, quats_a: np.ndarray, log_scales_a: np.ndarray,
          means_b: np.ndarray, quats_b: np.ndarray, log_scales_b: np.ndarray, *,
          dtype: type = np.float64) -> np.ndarray:
    """Return W2^2 between pairs of Gaussians given by raw 3DGS parameters, ``[M]``.

    Args:
        means_a: ``[M, 3]`` centres of the first Gaussians.
        quats_a: ``[M, 4]`` rotations w,x,y,z (not necessarily normalised).
        log_scales_a: ``[M, 3]`` log standard deviations (-inf for a zero axis).
        means_b: ``[M, 3]`` centres of the second Gaussians.
        quats_b: ``[M, 4]``.
        log_scales_b: ``[M, 3]``.
        dtype: compute dtype, ``np.float64`` or ``np.float32`` (see the module's error bound).

    Example:
        >>> mu = np.zeros((1, 3)); q = np.array([[1.0, 0, 0, 0]])
        >>> float(w2_sq(mu, q, np.log([[1.0, 2.0, 3.0]]), mu + [[3.0, 0, 0]], q, np.log([[1.0, 1.0, 1.0]]))[0])
        14.0
    """
    means_a = np.asarray(means_a).reshape(-1, 3)
    means_b = np.asarray(means_b).reshape(-1, 3)
    if means_a.shape != means_b.shape:
        raise CloudError(f"means_a {list(means_a.shape)} and means_b {list(means_b.shape)} must match")
    a = gaussian_shapes(quats_a, log_scales_a, dtype)
    b = gaussian_shapes(quats_b, log_scales_b, dtype)
    if len(a) != len(means_a) or len(b) != len(means_b):
        raise CloudError("every pair needs a mean, a quaternion and log-scales")
    diff = means_a.astype(dtype) - means_b.astype(dtype)
    return w2_sq_shapes(np.einsum("ij,ij->i", diff, diff), a, b)


def w2_sq_covariances(means_a: np.ndarray, covs_a: np.ndarray, means_b: np.ndarray,
                      covs_b: np.ndarray) -> np.ndarray:
    """Return W2^2 between pairs of Gaussians given by arbitrary SPD covariances ``[M, 3, 3]``, in float64, ``[M]``.

    The invariants of S_a S_b come from Frobenius products: I1 = <S_a, S_b>, I2 = <adj S_a, adj S_b>,
    p = sqrt(det S_a det S_b). These can cancel (absolute error about u |S_a| |S_b|), so the result is accurate to
    about sqrt(u) relative to tr S_a + tr S_b; prefer :func:`w2_sq` when rotations and scales are known.
    """
    ma = np.asarray(means_a, dtype=np.float64).reshape(-1, 3)
    mb = np.asarray(means_b, dtype=np.float64).reshape(-1, 3)
    sa = np.asarray(covs_a, dtype=np.float64).reshape(-1, 3, 3)
    sb = np.asarray(covs_b, dtype=np.float64).reshape(-1, 3, 3)
    if not (len(ma) == len(mb) == len(sa) == len(sb)):
        raise CloudError("means and covariances must have the same number of pairs")
    sa = 0.5 * (sa + sa.transpose(0, 2, 1))
    sb = 0.5 * (sb + sb.transpose(0, 2, 1))

    def adj(s: np.ndarray) -> np.ndarray:
        a, b, c = s[:, 0, 0], s[:, 1, 1], s[:, 2, 2]
        d, e, f = s[:, 0, 1], s[:, 0, 2], s[:, 1, 2]
        out = np.empty_like(s)
        out[:, 0, 0] = b * c - f * f
        out[:, 1, 1] = a * c - e * e
        out[:, 2, 2] = a * b - d * d
        out[:, 0, 1] = out[:, 1, 0] = e * f - d * c
        out[:, 0, 2] = out[:, 2, 0] = d * f - e * b
        out[:, 1, 2] = out[:, 2, 1] = d * e - a * f
        return out

    i1 = np.einsum("nij,nij->n", sa, sb)
    i2 = np.einsum("nij,nij->n", adj(sa), adj(sb))
    det = np.maximum(np.linalg.det(sa), 0) * np.maximum(np.linalg.det(sb), 0)
    t = sum_sqrt_eigenvalues(i1, i2, np.sqrt(det))
    bures = np.maximum(np.trace(sa, axis1=1, axis2=2) + np.trace(sb, axis1=1, axis2=2) - 2 * t, 0)
    diff = ma - mb
    return np.einsum("ij,ij->i", diff, diff) + bures


def w2_sq_neighbors(means: np.ndarray, shapes: GaussianShapes, neighbors: np.ndarray, *,
                    dist2: np.ndarray | None = None, rows: np.ndarray | None = None, chunk_rows: int = 1 << 14,
                    threads: int = 2, progress: ProgressFactory = null_progress) -> np.ndarray:
    """Return W2^2 from each Gaussian to each of its neighbours, ``[R, K]`` in the shapes' dtype.

    Args:
        means: ``[N, 3]`` centres.
        shapes: per-Gaussian shapes of all N Gaussians (:func:`gaussian_shapes`).
        neighbors: ``[R, K]`` neighbour indices into the N Gaussians.
        dist2: ``[R, K]`` squared centre distances, if known; used for float32 shapes only (float64 recomputes
            them from ``means`` so the result keeps float64 accuracy).
        rows: ``[R]`` index of the Gaussian each row belongs to (default ``arange(N)``, R = N).
        chunk_rows: rows per chunk; bounds the temporary memory to about 60 arrays of chunk_rows * K values.
        threads: worker threads (numpy releases the GIL inside its loops).
        progress: progress factory; one step per row.
    """
    neighbors = np.asarray(neighbors)
    n_rows, k = neighbors.shape
    rows = np.arange(n_rows) if rows is None else np.asarray(rows)
    if rows.shape != (n_rows,):
        raise CloudError(f"rows must have shape [{n_rows}], got {list(rows.shape)}")
    dtype = shapes.trace.dtype
    out = np.empty((n_rows, k), dtype=dtype)

    def work(start: int) -> int:
        stop = min(n_rows, start + chunk_rows)
        nb = neighbors[start:stop]
        own = rows[start:stop]
        if dist2 is None or dtype != np.float32:
            diff = means[nb].astype(dtype) - means[own][:, None, :].astype(dtype)
            d2 = np.einsum("rkc,rkc->rk", diff, diff)
        else:
            d2 = dist2[start:stop]
        a = shapes.take(own)
        a = GaussianShapes(a.quats[:, None, :], a.sq[:, None, :], a.cof[:, None, :], a.det_sqrt[:, None],
                           a.trace[:, None])
        out[start:stop] = w2_sq_shapes(d2, a, shapes.take(nb))
        return stop - start

    starts = range(0, n_rows, chunk_rows)
    with progress(total=n_rows, desc="W2 to neighbours") as bar:
        if threads > 1 and n_rows > chunk_rows:
            with ThreadPoolExecutor(max_workers=threads) as pool:
                for done in pool.map(work, starts):
                    bar.update(done)
        else:
            for start in starts:
                bar.update(work(start))
    return out
