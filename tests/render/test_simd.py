"""The compositing's 16-lane values (roodi_toolkit.render.simd): every operation gives, lane by lane, exactly the
bits of the scalar code it stands for (the forward walks on vectors and the backward recomputes its alphas: any
difference would make them disagree on which pixels blended), in float32 and float64."""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import pytest
from numba.core.errors import TypingError

from roodi_toolkit.render import simd
from roodi_toolkit.render.lanes import _constant_tuple, _constants, _fma, _gauss, _pick, _stack_empty
from roodi_toolkit.render.vectors import _columns_into, _lane_dots_into, _lane_sums_into, _sh_sums, _sh_weights

DTYPES = [np.float32, np.float64]


def _awkward(rng, dtype, n=16):
    """Values over twelve orders of magnitude, both signs, zeros of both signs, a NaN and infinities."""
    v = (rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 6, n)).astype(dtype)
    v[[1, 4, 7, 11]] = [0.0, -0.0, np.nan, np.inf]
    return v


@nb.njit
def _vector_ops(x, y, z, s):
    vx, vy, vz = simd.load(x, 0), simd.load(y, 0), simd.load(z, 0)
    out = np.empty((9, 16), x.dtype)
    simd.store(out[0], 0, vx + vy)
    simd.store(out[1], 0, vx - s)
    simd.store(out[2], 0, s * vy)
    simd.store(out[3], 0, vx / vy)
    simd.store(out[4], 0, -vx)
    simd.store(out[5], 0, min(vx, s))
    simd.store(out[6], 0, min(s, vy))
    simd.store(out[7], 0, _fma(vx, vy, vz))
    simd.store(out[8], 0, _pick((vx > vy) & ~(vy < s) | (vz >= s), vx, s))
    return out


@nb.njit(error_model="numpy")  # IEEE division (x / 0: inf or NaN), as the vectors'
def _scalar_ops(x, y, z, s):
    out = np.empty((9, 16), x.dtype)
    for q in range(16):
        out[0, q] = x[q] + y[q]
        out[1, q] = x[q] - s
        out[2, q] = s * y[q]
        out[3, q] = x[q] / y[q]
        out[4, q] = -x[q]
        out[5, q] = min(x[q], s)
        out[6, q] = min(s, y[q])
        out[7, q] = _fma(x[q], y[q], z[q])
        out[8, q] = x[q] if ((x[q] > y[q]) and not (y[q] < s)) or (z[q] >= s) else s
    return out


@pytest.mark.parametrize("dtype", DTYPES)
def test_vector_arithmetic_equals_the_scalar_code_bit_for_bit(dtype):
    """Sums, differences, products and quotients with vectors and broadcast scalars, negation (the sign of zero),
    ``min`` (numba's: the first argument where either is NaN), fused multiply-add, comparisons, masks and selects."""
    rng = np.random.default_rng(0)
    with np.errstate(all="ignore"):
        for _ in range(10):
            x, y, z = (_awkward(rng, dtype) for _ in range(3))
            s = dtype(rng.standard_normal())
            got, want = _vector_ops(x, y, z, s), _scalar_ops(x, y, z, s)
            assert np.array_equal(got.view(np.uint8), want.view(np.uint8))  # bits, NaN and -0.0 included


@nb.njit
def _gauss_both(dx, dy, ha, b, hc, like):
    kt = _constant_tuple(_constants(like))
    vec = np.empty(16, like.dtype)
    simd.store(vec, 0, _gauss(simd.load(dx, 0), simd.load(dy, 0), ha, b, hc, kt))
    one = np.empty(16, like.dtype)
    for q in range(16):
        one[q] = _gauss(dx[q], dy[q], ha, b, hc, kt)
    return vec, one


@pytest.mark.parametrize("dtype", DTYPES)
def test_the_gaussian_on_vectors_is_the_scalar_one_bit_for_bit(dtype):
    """The forward evaluates a Gaussian on a block's 16 pixels as one vector, the backward recomputes it: the same
    expression (``lanes._gauss``, its polynomial and clamp) gives the same bits either way, inside and past the
    footprint (sigma clamped)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        dx, dy = (rng.uniform(-8, 8, 16).astype(dtype) for _ in range(2))
        ha, hc = (dtype(rng.uniform(0.01, 2.0)) for _ in range(2))
        b = dtype(rng.uniform(-1, 1) * 2 * math.sqrt(ha * hc))
        vec, one = _gauss_both(dx, dy, ha, b, hc, dx)
        assert np.array_equal(vec, one)


@nb.njit
def _tests(x, s):
    v = simd.load(x, 0)
    return simd.any_lane(v > s), simd.any_lane(v < s), simd.any_lane(v != v)


def test_any_lane_and_an_integer_vector_select():
    x = np.arange(16, dtype=np.float32)
    assert _tests(x, np.float32(14.5)) == (True, True, False)
    assert _tests(x, np.float32(15.0)) == (False, True, False)
    assert _tests(x, np.float32(-1.0)) == (True, False, False)
    x[9] = np.nan  # NaN != NaN, as in Python
    assert _tests(x, np.float32(20.0)) == (False, True, True)

    @nb.njit
    def last(alpha):  # the forward's walked count: the entry's number where the pixel blended
        lv = simd.splat(np.int32(0))
        for j in range(alpha.shape[0]):
            lv = _pick(simd.load(alpha[j], 0) > np.float32(0.5), np.int32(j + 1), lv)
        out = np.empty(16, np.int32)
        simd.store(out, 0, lv)
        return out

    alpha = np.random.default_rng(2).random((7, 16)).astype(np.float32)
    want = np.array([max([j + 1 for j in range(7) if alpha[j, q] > 0.5], default=0) for q in range(16)])
    assert np.array_equal(last(alpha), want)


def test_a_float64_scalar_never_meets_float32_lanes():
    """A float literal in a float32 walk would turn its arithmetic into float64: a typing error instead."""

    @nb.njit
    def mixed(x):
        return simd.any_lane(simd.load(x, 0) * 2.0 > np.float32(1.0))

    with pytest.raises(TypingError):
        mixed(np.zeros(16, np.float32))


@pytest.mark.parametrize("dtype", DTYPES)
def test_sums_of_vector_rows_equal_those_of_stack_rows(dtype):
    """The backward's pair sums from vectors (a tuple of rows, a vector of weights) are those of the same lanes in
    stack arrays, bit for bit."""

    @nb.njit
    def run(rows, w, geom_v, geom_s, chan_v, chan_s):
        six = nb.carray(_stack_empty(96, rows.dtype), (6, 16))
        six[:, :] = rows[:6]
        four = nb.carray(_stack_empty(64, rows.dtype), (4, 16))
        four[:, :] = rows[6:10]
        wl = nb.carray(_stack_empty(16, rows.dtype), (16,))
        wl[:] = w
        vs = (simd.load(rows[0], 0), simd.load(rows[1], 0), simd.load(rows[2], 0), simd.load(rows[3], 0),
              simd.load(rows[4], 0), simd.load(rows[5], 0))
        gs = (simd.load(rows[6], 0), simd.load(rows[7], 0), simd.load(rows[8], 0), simd.load(rows[9], 0))
        _lane_sums_into(vs, 6, geom_v, 1)
        _lane_sums_into(six, 6, geom_s, 1)
        _lane_dots_into(simd.load(w, 0), gs, 4, chan_v, 0)
        _lane_dots_into(wl, four, 4, chan_s, 0)

    rng = np.random.default_rng(3)
    for _ in range(5):
        rows = (rng.standard_normal((10, 16)) * 10.0 ** rng.uniform(-3, 3, (10, 16))).astype(dtype)
        w = rng.standard_normal(16).astype(dtype)
        geom = rng.standard_normal((2, 6)).astype(dtype)
        chan = rng.standard_normal((1, 4)).astype(dtype)
        gv, gs, cv, cs = geom.copy(), geom.copy(), chan.copy(), chan.copy()
        run(rows, w, gv, gs, cv, cs)
        assert np.array_equal(gv, gs) and np.array_equal(cv, cs) and not np.array_equal(gv, geom)


@pytest.mark.parametrize("dtype", DTYPES)
def test_columns_of_sixteen_rows(dtype):
    """The projection's group buffer filled from 16 rows of an [N, k] array by one load and shuffles: row ``row + c``
    of the buffer is column ``c`` of the rows ``first``..``first + 15``, widened to float64, and no other row moves."""

    @nb.njit
    def run(src3, src4, first, dst):
        _columns_into(dst, 1, src3, first, 3)
        _columns_into(dst, 5, src4, first, 4)

    rng = np.random.default_rng(4)
    src3 = rng.standard_normal((40, 3)).astype(dtype)
    src4 = rng.standard_normal((40, 4)).astype(dtype)
    dst = np.full((12, 16), 7.0)
    run(src3, src4, 21, dst)
    want = np.full((12, 16), 7.0)
    want[1:4] = src3[21:37].T
    want[5:9] = src4[21:37].T
    assert np.array_equal(dst, want)


def test_the_projection_refuses_rows_it_would_misread():
    """The projection reads 16 rows of means, quaternions and scales as one vector each: arrays whose rows are not
    3, 4 and 3 long are refused, not misread, and strided ones are read like contiguous ones."""
    from roodi_toolkit.render import fast

    view = fast.make_view(np.eye(4), np.array([[64.0, 0, 32], [0, 64, 32], [0, 0, 1]]), 64, 64)
    n = 40
    means = np.zeros((n, 3), np.float32)
    means[:, 2] = 2.0
    quats = np.tile(np.float32([1, 0, 0, 0]), (n, 1))
    args = (np.full((n, 3), -3.0, np.float32), np.zeros(n, np.float32), np.ones((n, 1, 3), np.float32), 0, view)
    want = fast.project(means, quats, *args)
    assert want.ntiles.sum() > 0
    wide = np.zeros((n, 6), np.float32)
    wide[:, ::2] = means  # a strided view is copied into C order, not refused
    assert np.array_equal(fast.project(wide[:, ::2], quats, *args).means2d, want.means2d)
    with pytest.raises(ValueError, match="quaternions"):
        fast.project(means, np.ascontiguousarray(quats[:, :3]), *args)


@nb.njit
def _sh_scalar(basis, sh, i, n, g0, g1, g2, g_sh):  # the loops the SH helpers stand for
    v0 = v1 = v2 = 0.5
    w = np.zeros(16)
    for k in range(n):
        bk = basis[k]
        v0 += bk * sh[i, k, 0]
        v1 += bk * sh[i, k, 1]
        v2 += bk * sh[i, k, 2]
        g_sh[i, k, 0] = bk * g0
        g_sh[i, k, 1] = bk * g1
        g_sh[i, k, 2] = bk * g2
        w[k] = g0 * sh[i, k, 0] + g1 * sh[i, k, 1] + g2 * sh[i, k, 2]
    return (v0, v1, v2), w


@nb.njit
def _sh_vector(values, sh, i, n, g0, g1, g2, g_sh):
    basis = nb.carray(_stack_empty(16, values), (16,))
    basis[:] = values
    if n == 16:
        v = _sh_sums(basis, sh, i, 16, 0.5)
        w = _sh_weights(basis, sh, g_sh, i, 16, g0, g1, g2)
    elif n == 9:
        v = _sh_sums(basis, sh, i, 9, 0.5)
        w = _sh_weights(basis, sh, g_sh, i, 9, g0, g1, g2)
    elif n == 4:
        v = _sh_sums(basis, sh, i, 4, 0.5)
        w = _sh_weights(basis, sh, g_sh, i, 4, g0, g1, g2)
    else:
        v = _sh_sums(basis, sh, i, 1, 0.5)
        w = _sh_weights(basis, sh, g_sh, i, 1, g0, g1, g2)
    out = np.empty(16)
    for k in range(16):
        out[k] = w[k]
    return v, out


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("n", [1, 4, 9, 16])
def test_sh_channels_as_lanes_equal_the_scalar_loops_bit_for_bit(dtype, n):
    """A Gaussian's SH colour, its coefficients' gradients and the weights of the direction's gradient, on vectors,
    are those of the scalar loops, bit for bit, for every degree (of 16 coefficients a row); the gradients' row past
    the degree is left alone and the weights past it are 0."""
    rng = np.random.default_rng(5 + n)
    for _ in range(4):
        values = rng.standard_normal(16) * 10.0 ** rng.uniform(-2, 2, 16)
        sh = (rng.standard_normal((6, 16, 3)) * 10.0 ** rng.uniform(-3, 1, (6, 16, 3))).astype(dtype)
        g = rng.standard_normal(3)
        g_scalar = np.full(sh.shape, 9.0, dtype)
        g_vector = g_scalar.copy()
        want = _sh_scalar(values, sh, 4, n, g[0], g[1], g[2], g_scalar)
        got = _sh_vector(values, sh, 4, n, g[0], g[1], g[2], g_vector)
        assert got[0] == want[0] and np.array_equal(got[1], want[1])
        assert np.array_equal(g_vector, g_scalar) and (g_vector[4, n:] == 9.0).all()


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_direction_gradient_is_that_of_the_bases(degree):
    """The direction's gradient from the weights of the bases (written out term by term) is autograd's gradient of
    the weighted sum of the SH bases (``roodi_toolkit.sh.sh_bases``) at unit directions."""
    import torch

    from roodi_toolkit.render.projection_kernels import _sh_direction_grad
    from roodi_toolkit.sh import sh_bases

    @nb.njit
    def grad(w, n, d):
        return _sh_direction_grad((w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7], w[8], w[9], w[10], w[11],
                                   w[12], w[13], w[14], w[15]), n, d[0], d[1], d[2])

    rng = np.random.default_rng(11 + degree)
    n = (degree + 1) ** 2
    for _ in range(5):
        d = rng.standard_normal(3)
        d /= np.linalg.norm(d)
        w = np.zeros(16)
        w[:n] = rng.standard_normal(n)
        dirs = torch.tensor(d[None], requires_grad=True)
        ((sh_bases(degree, dirs)[0] * torch.from_numpy(w[:n])).sum() + 0.0 * dirs.sum()).backward()  # SH 0: constant
        assert np.allclose(grad(w, n, d), dirs.grad[0].numpy(), rtol=1e-12, atol=1e-12)
