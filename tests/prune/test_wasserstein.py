"""W2^2 between Gaussians: closed form against scipy.linalg.sqrtm and a 40-digit reference; the error bound."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.linalg import LinAlgWarning, sqrtm

from roodi_toolkit.gaussians import quat_to_rotmat
from roodi_toolkit.prune.wasserstein import (W2_ERROR_FACTOR, gaussian_shapes, sum_sqrt_eigenvalues, w2_sq,
                                       w2_sq_covariances, w2_sq_neighbors)

CASES = ("random", "identical", "degenerate", "tiny", "anisotropic", "far")


def w2_sq_reference(means_a: np.ndarray, covs_a: np.ndarray, means_b: np.ndarray, covs_b: np.ndarray) -> np.ndarray:
    """Return W2^2 per pair with ``scipy.linalg.sqrtm`` in float64, ``[M]``: the slow reference (from the
    definition, no closed form)."""
    ma = np.asarray(means_a, dtype=np.float64).reshape(-1, 3)
    mb = np.asarray(means_b, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(ma))
    for n, (sa, sb) in enumerate(zip(np.asarray(covs_a, np.float64), np.asarray(covs_b, np.float64))):
        rb = np.real(sqrtm(sb))
        cross = np.real(sqrtm(rb @ sa @ rb))
        out[n] = float(np.sum((ma[n] - mb[n]) ** 2) + np.trace(sa) + np.trace(sb) - 2 * np.trace(cross))
    return out


def _covs(quats: np.ndarray, log_scales: np.ndarray) -> np.ndarray:
    R = quat_to_rotmat(quats)
    return np.einsum("nij,nj,nkj->nik", R, np.exp(2 * log_scales.astype(np.float64)), R)


def _pairs(case: str, m: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    qa, qb = rng.normal(size=(m, 4)), rng.normal(size=(m, 4))
    la, lb = rng.normal(size=(m, 3)), rng.normal(size=(m, 3))
    ma, mb = rng.normal(size=(m, 3)), rng.normal(size=(m, 3))
    if case == "identical":
        qb, lb, mb = qa.copy(), la.copy(), ma.copy()
    elif case == "degenerate":  # flat Gaussians: a zero axis
        la[:, 2] = -np.inf
        lb[::2, 0] = -np.inf
    elif case == "tiny":
        la[:, 2] = -20.0
        lb[:, 1] = -25.0
    elif case == "anisotropic":  # needles, 1e4:1, crossing
        la = np.tile([3.0, -6.2, -6.2], (m, 1))
        lb = la[:, [1, 0, 2]].copy()
    elif case == "far":
        mb = ma + 1e4
    return ma, qa, la, mb, qb, lb


def _scale(ma, la, mb, lb) -> np.ndarray:
    return np.sum((ma - mb) ** 2, axis=1) + np.exp(2 * la).sum(axis=1) + np.exp(2 * lb).sum(axis=1)


@pytest.mark.parametrize("case", CASES)
def test_matches_scipy_sqrtm_reference(case):
    ma, qa, la, mb, qb, lb = _pairs(case, 300)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LinAlgWarning)  # sqrtm of singular covariances
        ref = w2_sq_reference(ma, _covs(qa, la), mb, _covs(qb, lb))
    got = w2_sq(ma, qa, la, mb, qb, lb)
    scale = _scale(ma, la, mb, lb)
    # sqrtm of a singular matrix is itself only accurate to about sqrt(u); elsewhere agree to round-off
    tol = 1e-7 if case in ("degenerate", "tiny", "anisotropic") else 1e-12
    assert np.all(np.abs(got - ref) <= tol * scale)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_error_bound_against_40_digit_reference(case, dtype):
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 40
    ma, qa, la, mb, qb, lb = _pairs(case, 25, seed=1)

    def cov(q, ls):
        q = [mpmath.mpf(float(v)) for v in q]
        norm = mpmath.sqrt(sum(v * v for v in q))
        w, x, y, z = (v / norm for v in q)
        R = mpmath.matrix([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                           [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                           [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        D = mpmath.diag([mpmath.e ** mpmath.mpf(float(v)) if np.isfinite(v) else mpmath.mpf(0) for v in ls])
        return R * D * D * R.T, R * D * R.T

    ref = []
    for n in range(len(ma)):
        sa, _ = cov(qa[n], la[n])
        sb, rb = cov(qb[n], lb[n])
        m = rb * sa * rb
        t = sum(mpmath.sqrt(max(e, 0)) for e in mpmath.eigsy((m + m.T) / 2)[0])
        d2 = sum((mpmath.mpf(float(ma[n, c])) - mpmath.mpf(float(mb[n, c]))) ** 2 for c in range(3))
        ref.append(float(d2 + sum(sa[i, i] + sb[i, i] for i in range(3)) - 2 * t))
    got = w2_sq(ma, qa, la, mb, qb, lb, dtype=dtype).astype(np.float64)
    u = np.finfo(dtype).eps / 2
    assert np.all(np.abs(got - np.array(ref)) <= W2_ERROR_FACTOR * u * _scale(ma, la, mb, lb))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("case", CASES)
def test_never_below_centre_distance(case, dtype):
    ma, qa, la, mb, qb, lb = _pairs(case, 500, seed=2)
    got = w2_sq(ma, qa, la, mb, qb, lb, dtype=dtype)
    diff = ma.astype(dtype) - mb.astype(dtype)
    assert np.all(got >= np.einsum("ij,ij->i", diff, diff))
    assert got.dtype == dtype


def test_identical_gaussians_are_at_zero_and_symmetry():
    ma, qa, la, mb, qb, lb = _pairs("identical", 50)
    scale = _scale(ma, la, mb, lb)
    assert np.all(w2_sq(ma, qa, la, mb, qb, lb) <= 8 * np.finfo(float).eps * scale)
    ma, qa, la, mb, qb, lb = _pairs("random", 50)
    np.testing.assert_allclose(w2_sq(ma, qa, la, mb, qb, lb), w2_sq(mb, qb, lb, ma, qa, la), rtol=1e-12)


def test_known_values():
    mu = np.zeros((2, 3))
    q = np.tile([1.0, 0, 0, 0], (2, 1))
    # commuting covariances: Bures^2 = sum (s_a - s_b)^2
    la = np.log([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]])
    lb = np.log([[2.0, 2.0, 1.0], [0.5, 0.5, 0.5]])
    np.testing.assert_allclose(w2_sq(mu, q, la, mu + [[1, 2, 2], [0, 0, 0]], q, lb), [9 + 1 + 0 + 4, 0], atol=1e-14)
    # a quaternion sign flip and scaling is the same rotation
    rng = np.random.default_rng(3)
    qr = rng.normal(size=(2, 4))
    np.testing.assert_allclose(w2_sq(mu, qr, la, mu, -3 * qr, la), 0, atol=1e-14)


def test_sum_sqrt_eigenvalues_including_rank_deficient():
    rng = np.random.default_rng(4)
    lam = rng.random((1000, 3)) ** 4
    lam[:100, 1:] = 0  # rank 1
    lam[100:200, 2] = 0  # rank 2
    lam[200:210] = 0
    i1 = lam.sum(1)
    i2 = lam[:, 0] * lam[:, 1] + lam[:, 1] * lam[:, 2] + lam[:, 0] * lam[:, 2]
    t = sum_sqrt_eigenvalues(i1, i2, np.sqrt(lam.prod(1)))
    np.testing.assert_allclose(t, np.sqrt(lam).sum(1), rtol=1e-14, atol=0)


def test_covariance_form_agrees():
    ma, qa, la, mb, qb, lb = _pairs("random", 200, seed=5)
    np.testing.assert_allclose(w2_sq_covariances(ma, _covs(qa, la), mb, _covs(qb, lb)), w2_sq(ma, qa, la, mb, qb, lb),
                               rtol=1e-9)


def test_neighbors_chunked_threaded_matches_pairs():
    rng = np.random.default_rng(6)
    n, k = 3000, 5
    means = rng.normal(size=(n, 3)).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    ls = rng.normal(-2, 0.5, size=(n, 3)).astype(np.float32)
    nb = rng.integers(0, n, size=(n, k))
    shapes = gaussian_shapes(quats, ls, np.float64)
    got = w2_sq_neighbors(means, shapes, nb, chunk_rows=257, threads=2)
    rows = np.repeat(np.arange(n), k)
    ref = w2_sq(means[rows], quats[rows], ls[rows], means[nb.ravel()], quats[nb.ravel()], ls[nb.ravel()])
    np.testing.assert_allclose(got.ravel(), ref, rtol=1e-12, atol=1e-15)
