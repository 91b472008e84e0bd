"""The 4x4 pixel blocks of the compositing kernels (:mod:`roodi_toolkit.render.kernels`): the constants, the stack
arrays that hold a block's pixels between walks, and the arithmetic every walk shares.

A walk's state is a set of 16-lane vectors (:mod:`.simd`), and the arithmetic here (:func:`_gauss`, the
exponential, :func:`_fma`, :func:`_pick`) runs unchanged on a scalar or on such a vector, with the same bits in every
lane as the scalar code (``tests/render/test_simd.py``): the forward and the backward recompute each alpha alike.
Every constant comes in the inputs' dtype as a tuple of values (:func:`_constant_tuple`; a float literal would turn
float32 arithmetic into float64). Stack arrays of a constant size (:func:`_stack_empty`), never on the heap (which
would need runtime overlap checks), hold what goes in and out of a block's walk and the channels past four; what a
loop over them does not express well is written as LLVM vector operations on the 16 lanes (:mod:`.vectors`).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

from . import simd
from .vectors import LANES

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4
SIGMA_MAX = 6.0
"""Beyond this Mahalanobis half-square, ``opacity * exp(-sigma) < 1/255`` for any opacity: the alpha test drops the
pixel, so the Gaussian's value there is computed on ``SIGMA_MAX`` instead (keeps the polynomial in its range)."""
I3, I4, I5, I6, I7, I8, I9, I10 = (1.0 / math.factorial(k) for k in range(3, 11))  # Taylor coefficients of exp


@intrinsic
def _stack_empty(typingctx, size, dtype):  # pragma: no cover - compiled
    """A pointer to ``size`` uninitialised values of ``dtype`` on the calling function's stack: ``size`` is an integer
    literal, or a tuple of ``G`` channel groups for ``G * 4 * 16`` values (four channels of a 4x4 block's pixels per
    group: the tuple's length is known when compiling, so the kernels are compiled once per group count).

    Arrays made of it (:func:`numba.carray`) are known to alias nothing else, so LLVM keeps them in vector registers
    and vectorises loops over them without runtime overlap checks; heap arrays would be read and written through
    memory on every Gaussian."""
    if isinstance(size, types.IntegerLiteral):
        n = size.literal_value
    elif isinstance(size, types.BaseTuple):
        n = len(size) * 4 * LANES
    else:
        return None

    def codegen(context, builder, signature, args):  # the alloca goes to the entry block: its size is a constant
        slot = cgutils.alloca_once(builder, context.get_value_type(dtype.dtype),
                                   size=context.get_constant(types.intp, n))
        slot.align = 64  # a cache line: 16 float32 lanes never straddle two, wherever the process's stack lies
        return slot

    return types.CPointer(dtype.dtype)(size, dtype), codegen


@nb.njit(inline="always")
def _lanes(dtype_of):  # pragma: no cover - compiled
    """16 values of ``dtype_of``'s dtype on the stack: one per pixel of a 4x4 block."""
    return nb.carray(_stack_empty(16, dtype_of.dtype), (LANES,))


@nb.njit(inline="always")
def _constants(like):  # pragma: no cover - compiled
    """The compositing constants in ``like``'s dtype (a float literal would turn float32 arithmetic into float64)."""
    kc = np.empty(16, like.dtype)
    kc[0] = ALPHA_MIN
    kc[1] = ALPHA_MAX
    kc[2] = TRANSMITTANCE_MIN
    kc[3] = SIGMA_MAX
    kc[4] = -0.0625
    kc[5] = 0.5
    kc[6] = 1.0
    kc[7] = 0.0
    kc[8] = I3
    kc[9] = I4
    kc[10] = I5
    kc[11] = I6
    kc[12] = I7
    kc[13] = I8
    kc[14] = I9
    kc[15] = I10
    return kc


@nb.njit(inline="always")
def _constant_tuple(kc):  # pragma: no cover - compiled
    """:func:`_constants` as a tuple: values the compiled loops hold in registers (no loads from memory)."""
    return (kc[0], kc[1], kc[2], kc[3], kc[4], kc[5], kc[6], kc[7], kc[8], kc[9], kc[10], kc[11], kc[12], kc[13],
            kc[14], kc[15])


@intrinsic
def _fma(typingctx, a, b, c):  # pragma: no cover - compiled
    """``a * b + c`` with one rounding where the CPU has fused multiply-add (LLVM's ``fmuladd``); lane by lane where
    an operand is a :class:`~.simd.Vec` (the others its dtype's scalars)."""
    if not (isinstance(a, types.Float) and a == b and b == c):
        return simd.fma_typed(a, b, c)

    def codegen(context, builder, signature, args):
        ty = context.get_value_type(signature.return_type)
        fn = builder.module.declare_intrinsic("llvm.fmuladd", [ty], ir.FunctionType(ty, [ty, ty, ty]))
        return builder.call(fn, args)

    return a(a, b, c), codegen


@intrinsic
def _pick(typingctx, cond, a, b):  # pragma: no cover - compiled
    """``a if cond else b`` as one LLVM ``select``. Numba lowers a conditional expression to branches that LLVM
    if-converts inside the vectorised loops over the lanes, but where the value is stored into a lane array it made
    two masked stores of it (found in the assembly), and the vector load after the loop then waited for both to
    reach the cache (no store-to-load forwarding from a masked store). Lane by lane where ``cond`` is a
    :class:`~.simd.Mask` (:func:`~.simd.select`)."""
    if not (isinstance(cond, types.Boolean) and a == b):
        return simd.select_typed(cond, a, b)

    def codegen(context, builder, signature, args):
        return builder.select(args[0], args[1], args[2])

    return a(cond, a, b), codegen


@intrinsic
def _prefetch(typingctx, arr, index):  # pragma: no cover - compiled
    """Ask the CPU to bring element ``index`` of the C-contiguous ``arr``'s data into its caches (LLVM's
    ``prefetch``: a hint, no fault, no result)."""
    if not (isinstance(arr, types.Array) and isinstance(index, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = builder.module.declare_intrinsic("llvm.prefetch", [i8p],
                                              ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]))
        builder.call(fn, [builder.bitcast(builder.gep(data, [args[1]]), i8p), i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    return types.none(arr, index), codegen


@nb.njit(inline="always")
def _prefetch_row(arr, lists, at):  # pragma: no cover - compiled
    """Prefetch the row of ``arr`` [N, K] (C-contiguous) of the Gaussian ``lists[at]``, where ``at`` is inside
    ``lists``: its first cache line, and its last where the row ends on another one (a 64-byte row that does not
    start on a line straddles two)."""
    if at < lists.shape[0]:
        first = np.int64(lists[at]) * arr.shape[1]
        _prefetch(arr, first)
        start = arr.ctypes.data + first * arr.itemsize
        if (start >> 6) != ((start + arr.shape[1] * arr.itemsize - 1) >> 6):
            _prefetch(arr, first + arr.shape[1] - 1)


PREFETCH = 32
"""How many entries of a tile's run ahead of the one it copies :func:`_pack` asks the CPU for the record of. The runs
are in depth order, so their records lie anywhere in memory: the gather's cache misses were an eighth of the
compositing (``benchmarks/profile_kernels.py``); 16 ahead measured 0.8-1.0x, 32 1.12x forward and 1.03x backward
(500k Gaussians, 800x800, one thread), 64 no better."""


EXP_F32 = (0.9999997581824221, 0.49999113524404704, 0.1665597530927115, 0.041096509237333115, 0.006923321748575962)
"""``exp(u) ~ 1 + u (c1 + c2 u + ... + c5 u^4)`` on ``[-0.375, 0]``, relative error 2.1e-9 (fitted for the least
largest relative error): in float32 the 16th power that follows amplifies rounding to 1.8e-6 whatever the degree
(the degree-10 Taylor series gives the same 1.8e-6), so float32 evaluates 5 terms where float64 needs 10."""


def _exp_series(u, kt):  # pragma: no cover - compiled (typed by the overload below)
    raise NotImplementedError


@overload(_exp_series, inline="always")
def _exp_series_typed(u, kt):
    """``exp(u)`` for ``u`` in ``[-0.375, 0]`` by Horner's scheme with fused multiply-adds: :data:`EXP_F32` in
    float32, the Taylor series to ``u^10 / 10!`` (``kt[8:16]``, relative error below 1e-11 after the 16th power) in
    float64."""
    if getattr(u, "dtype", u) == types.float32:  # a float32 number or :class:`~.simd.Vec`
        c1, c2, c3, c4, c5 = (np.float32(v) for v in EXP_F32)

        def impl(u, kt):  # pragma: no cover - compiled
            e = _fma(u, c5, c4)
            e = _fma(u, e, c3)
            e = _fma(u, e, c2)
            e = _fma(u, e, c1)
            return _fma(u, e, kt[6])

        return impl

    def impl(u, kt):  # pragma: no cover - compiled
        one = kt[6]
        e = _fma(u, kt[15], kt[14])
        e = _fma(u, e, kt[13])
        e = _fma(u, e, kt[12])
        e = _fma(u, e, kt[11])
        e = _fma(u, e, kt[10])
        e = _fma(u, e, kt[9])
        e = _fma(u, e, kt[8])
        e = _fma(u, e, kt[5])
        e = _fma(u, e, one)
        return _fma(u, e, one)

    return impl


@nb.njit(inline="always")
def _gauss(dx, dy, ha, b, hc, kt):  # pragma: no cover - compiled
    """``exp(-sigma)`` at offset (dx, dy) from the mean, ``sigma = ha dx^2 + b dx dy + hc dy^2`` clamped to
    ``SIGMA_MAX``, as ``exp(u)^16`` with ``u = -sigma / 16`` (:func:`_exp_series`): one expression for every walk,
    so the backward recomputes the forward's values bit for bit."""
    u = kt[4] * min(ha * dx * dx + b * dx * dy + hc * dy * dy, kt[3])
    e = _exp_series(u, kt)
    e *= e
    e *= e
    e *= e
    return e * e


@nb.njit(inline="always")
def _tile_box(t, tiles_x, tile, width, height):  # pragma: no cover - compiled
    """Return tile ``t``'s first and last pixel column and row (x_lo, y_lo, x_hi, y_hi), clipped to the image."""
    x_lo = (t % tiles_x) * tile
    y_lo = (t // tiles_x) * tile
    return x_lo, y_lo, min(x_lo + tile, width) - 1, min(y_lo + tile, height) - 1


@nb.njit(inline="always")
def _start_block(bx, by, x_hi, y_hi, pxc, pyc, T, one):  # pragma: no cover - compiled
    """Set the pixel centres ``pxc``, ``pyc`` of the 4x4 block at (bx, by) and its transmittances ``T``: 1, or -1
    (stopped from the start) for pixels past the tile's or image's last column ``x_hi`` or row ``y_hi``."""
    for q in range(LANES):
        px = bx + (q & 3)
        py = by + (q >> 2)
        pxc[q] = px + 0.5
        pyc[q] = py + 0.5
        T[q] = one if px <= x_hi and py <= y_hi else -one


@nb.njit(inline="always")
def _geometry(geo, jj):  # pragma: no cover - compiled
    """Return entry ``jj`` of the packed run (:func:`_pack`): mx, my, conic a, b, c, opacity, box x0, x1, y0, y1."""
    return (geo[jj, 0], geo[jj, 1], geo[jj, 2], geo[jj, 3], geo[jj, 4], geo[jj, 5], geo[jj, 6], geo[jj, 7],
            geo[jj, 8], geo[jj, 9])


@nb.njit(cache=True, nogil=True)
def _longest(busy, counts):  # pragma: no cover - compiled
    longest = 0
    for k in range(busy.shape[0]):
        longest = max(longest, counts[busy[k]])
    return longest


@nb.njit(inline="always")
def _pack(lists, s, lo, hi, rec, geo, box, gid):  # pragma: no cover - compiled
    """Copy entries ``lo:hi`` of the tile's run (from ``lists[s]``) next to each other from their records
    (:func:`fill_records`): each whole record (mx, my, conic a, b, c, opacity, the footprint box's x0, x1 + 1, y0,
    y1 + 1, then the four channels where it holds them) in ``geo`` [n, 16], copied as one vector (ten scalar copies
    and a copy of the channels apart before: the compositing 1.01-1.03x), the footprint box in ``box`` [n, 4], the
    id in ``gid`` [n]; every 4x4 block of the tile then reads them in order. Returns ``hi``."""
    for jj in range(lo, hi):
        _prefetch_row(rec, lists, s + jj + PREFETCH)
        g = lists[s + jj]
        gid[jj] = g
        simd.store(geo[jj], 0, simd.load(rec[g], 0))  # the whole record, channels included: one vector
        box[jj, 0] = np.int32(rec[g, 6])
        box[jj, 1] = np.int32(rec[g, 7]) - 1
        box[jj, 2] = np.int32(rec[g, 8])
        box[jj, 3] = np.int32(rec[g, 9]) - 1
    return hi


@nb.njit(parallel=True, cache=True, nogil=True)
def fill_records(bounds, means2d, conics, opacities, colors, nc, rec):  # pragma: no cover - compiled
    """Write each Gaussian's record into ``rec`` [N, 16] (64 bytes in float32, on a cache line: see
    :func:`roodi_toolkit.render.fast.records`): mx, my, conic a, b, c, opacity, the box's x0, x1 + 1, y0, y1 + 1,
    then its first ``nc`` channels (``nc`` 0 or 4; zero past ``colors``' own). A run's copy (:func:`_pack`,
    :func:`_pack_colours`) then gathers one cache line a Gaussian where it gathered one from each of five arrays (the
    compositing 1.12-1.19x forward and 1.17-1.25x backward at 500k Gaussians, 800x800, rgb + depth). More channels
    (16 features) stay in their own array: copied into 128-byte records they made the forward 0.87x."""
    C = colors.shape[1]
    for g in nb.prange(means2d.shape[0]):
        rec[g, 0] = means2d[g, 0]
        rec[g, 1] = means2d[g, 1]
        rec[g, 2] = conics[g, 0]
        rec[g, 3] = conics[g, 1]
        rec[g, 4] = conics[g, 2]
        rec[g, 5] = opacities[g]
        rec[g, 6] = bounds[g, 0]  # the box's edges as pixel-centre bounds: x0 < px + 0.5 < x1 + 1
        rec[g, 7] = bounds[g, 1] + 1
        rec[g, 8] = bounds[g, 2]
        rec[g, 9] = bounds[g, 3] + 1
        for ch in range(nc):
            rec[g, 10 + ch] = colors[g, ch] if ch < C else 0.0


@nb.njit(inline="always")
def _pack_colours(lists, s, lo, hi, colors, rec, colp):  # pragma: no cover - compiled
    """Copy the channels of entries ``lo:hi`` of the tile's run from ``colors`` into ``colp`` [n, 4 G], zero beyond
    ``C``, where there are more than four (four are in the records, which :func:`_pack` copies)."""
    C = colors.shape[1]
    NC = colp.shape[1]
    if NC > 4:  # (four are in the records' copy, :func:`_pack`; none where only the weights are listed)
        for jj in range(lo, hi):
            _prefetch_row(colors, lists, s + jj + PREFETCH)  # as the records in _pack
            g = lists[s + jj]
            for ch in range(NC):
                colp[jj, ch] = colors[g, ch] if ch < C else 0.0


@nb.njit(inline="always")
def _pack_blocks(lo, hi, box, x_lo, y_lo, nbx, blist, bcount):  # pragma: no cover - compiled
    """Append entries ``lo:hi`` of the packed run to the lists of the tile's 4x4 blocks (``blist[k, :bcount[k]]``,
    block ``k`` at column ``k % nbx`` and row ``k // nbx`` of the tile at ``x_lo``, ``y_lo``) that their footprint box
    touches: a block then walks only its own entries, in run order, instead of testing every entry's box (about one
    entry in five touches a given block at 500k Gaussians, 800x800)."""
    last = nbx - 1
    for jj in range(lo, hi):
        cx0 = max(0, (box[jj, 0] - x_lo) >> 2)
        cx1 = min(last, (box[jj, 1] - x_lo) >> 2)
        cy0 = max(0, (box[jj, 2] - y_lo) >> 2)
        cy1 = min(last, (box[jj, 3] - y_lo) >> 2)
        for cy in range(cy0, cy1 + 1):
            for cx in range(cx0, cx1 + 1):
                k = cy * nbx + cx
                blist[k, bcount[k]] = jj
                bcount[k] += 1


@nb.njit(inline="always")
def _next_entry(blk, p, packed, lists, s, n, rec, colors, geo, box, gid, colp, x_lo, y_lo, nbx, blist,
                bcount):  # pragma: no cover - compiled
    """Return (the run index of block ``blk``'s ``p``-th entry, or -1 past the run's end; how much of the run is
    copied): a block walking front to back copies the next 64 entries of the run (:func:`_pack`, their channels
    when ``colp`` has columns, and :func:`_pack_blocks`) when it has walked all of its own so far."""
    while p == bcount[blk]:
        if packed == n:
            return -1, packed
        lo = packed
        packed = _pack(lists, s, lo, min(n, lo + 64), rec, geo, box, gid)
        _pack_colours(lists, s, lo, packed, colors, rec, colp)
        _pack_blocks(lo, packed, box, x_lo, y_lo, nbx, blist, bcount)
    return blist[blk, p], packed


@intrinsic
def _lowest_bit(typingctx, m):  # pragma: no cover - compiled
    """The index of the lowest set bit of the nonzero unsigned integer ``m`` (LLVM's ``cttz``: one instruction)."""
    if not isinstance(m, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 1))

    return m(m), codegen


@nb.njit(inline="always")
def _pack_marked(lists, s, n, marks, rec, colors, geo, colp, run, blist, bcount):  # pragma: no cover - compiled
    """Copy the entries of the tile's run (``n`` from ``lists[s]``) that the forward marked as blended in at least
    one of the tile's 4x4 blocks (``marks`` [M, words], bit ``k`` of a pair's row: block ``k``), next to each other:
    slot ``p`` holds the ``run[p]``-th entry's record in ``geo`` (as :func:`_pack`; with the channels where there are
    four) and more channels in ``colp`` (as :func:`_pack_colours`), and is appended to the list of each block it is
    marked in (``blist[k, :bcount[k]]``).
    The backward then walks only what blended: a fifth of the entries whose box touches a block do not (500k
    Gaussians, 800x800), and their records are not gathered. Returns the number of slots."""
    C = colors.shape[1]
    NC = colp.shape[1]
    words = marks.shape[1]
    p = 0
    for jj in range(n):
        _prefetch_row(rec, lists, s + jj + PREFETCH)
        if NC > 4:
            _prefetch_row(colors, lists, s + jj + PREFETCH)
        any_mark = marks[s + jj, 0]
        for w in range(1, words):
            any_mark |= marks[s + jj, w]
        if any_mark == 0:
            continue
        g = lists[s + jj]
        simd.store(geo[p], 0, simd.load(rec[g], 0))  # the whole record, channels included: one vector
        if NC > 4:
            for ch in range(NC):
                colp[p, ch] = colors[g, ch] if ch < C else 0.0
        run[p] = jj
        for w in range(words):
            m = marks[s + jj, w]
            while m != 0:
                k = w * 64 + _lowest_bit(m)
                blist[k, bcount[k]] = p
                bcount[k] += 1
                m &= m - np.uint64(1)
        p += 1
    return p


def channel_groups(channels: int) -> tuple:
    """The ``groups`` argument of the compositing kernels for ``channels`` channels: one entry per group of 4
    channels, a power of two of them (the kernels hold 4 channels of a block's 16 pixels per group in registers and
    are compiled once per group count, about a minute each on a busy 2-core machine: 1, 2, 4, 8, ... keeps the
    count of compilations small; rgb + depth is 1, 16 features 4)."""
    groups = 1
    while 4 * groups < channels:
        groups *= 2
    return (0,) * groups
