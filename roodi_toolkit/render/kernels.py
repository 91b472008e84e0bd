"""Compiled CPU kernels of the default renderer: compositing forward and backward, the pairs' reduction (the depth
order and tile binning that make the runs they walk: :mod:`.tiles`).

Numba's parallel JIT (installed as a wheel with LLVM inside: no compiler on the user's machine) compiles these loops
to native code on first use and caches the result beside this file (``cache=True``), so later processes start at
once. The arithmetic is that of :mod:`roodi_toolkit.render.rasterizer` (3DGS "classic" mode, the same footprints,
depth order, alpha clamp and cut-offs); :mod:`roodi_toolkit.render.fast` wraps these kernels as a differentiable
torch function and the tests compare both with the dense reference.

Layout: the image is cut into square tiles (1 to 64 pixels wide); each tile holds the depth-ordered run of the
Gaussians whose footprint touches it (``lists[starts[t]:starts[t] + counts[t]]``). A worker takes every
``workers``-th busy tile (interleaved, so the busy parts of an image are shared out evenly) and composites it in 4x4
blocks of pixels: as the tile's run is copied, each entry is appended to the lists of the blocks its footprint box
touches (:func:`~.lanes._pack_blocks`); each block walks its list front to back (forward) and evaluates each
Gaussian on its 16 pixels at once (masked to the box). The forward marks, per (tile, Gaussian) pair, the blocks in
which it blended at least one pixel; the backward copies only the marked entries and walks each block's back to
front (:func:`~.lanes._pack_marked`). The 16 pixels' state (transmittance, walked count, channel sums, the
backward's sums behind) is a set of :class:`~.simd.Vec` values, one LLVM vector each, that stay in vector registers
from one entry to the next; each entry's parameters are broadcast into them, and a walk has no branch per pixel
(LLVM selects, :func:`~.lanes._pick`). Before, the state lived in 16-element stack arrays and each entry was a loop
over the lanes whose length was hidden from the compiler (a loop of a known 16 was unrolled and re-vectorised four
lanes at a time with spills): LLVM vectorised it, but loaded and stored every array at every entry, with a masked
remainder (ten loads and stores of 70 instructions; found in the assembly): the vectors made the compositing 1.35x
faster forward and 1.2x backward, the same bits. Four channels (rgb + depth) are added inside the walk; more in
vector steps after it (:mod:`.vectors`). A block walks its entries one at a time: two at a time (their alphas side
by side) ran out of vector registers and spilled every Gaussian's parameters.
Blocks at a tile's or the image's edge have their outside pixels stopped from the start.
Results do not depend on timing or on the number of workers: each tile is written by one worker, and the backward
writes one gradient per (tile, Gaussian) pair, summed over a block's 16 pixels in a fixed tree order and block after
block, which :func:`reduce_pairs` adds per Gaussian in pair order. A pixel's result does not depend on the tile size
either: its arithmetic uses only its own coordinates.

Per-pixel work is in the inputs' dtype (float32 inputs composite in float32, float64 ones, as the gradchecks use, in
float64, with the same code; every constant comes from an array of that dtype, as a float literal would promote
float32 to float64). ``exp(-sigma)`` is ``exp(u)^16`` with ``u = -sigma / 16`` and sigma clamped to ``SIGMA_MAX``,
``exp(u)`` a polynomial by Horner's scheme with fused multiply-adds (the Taylor series to ``u^10`` in float64,
relative error below 1e-11; a fitted degree-5 polynomial in float32, whose error after the 16th power is float32's
own rounding, as the series' is), one expression (:func:`_gauss`) for every walk. No fast-math flags: the values are
IEEE arithmetic in a fixed order (LLVM's ``fmuladd`` is fused on every CPU with FMA and split on the others, the same
in every kernel), so the backward recomputes exactly the forward's alphas and takes exactly its decisions. The
channels are held four to a group (:func:`channel_groups`); the kernels are compiled once per dtype and group count.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from . import simd
from .lanes import (LANES, PREFETCH, _constant_tuple, _constants, _fma, _gauss, _geometry, _lanes, _longest,
                    _next_entry, _pack_marked, _pick, _prefetch, _stack_empty, _start_block, _tile_box)
from .lanes import channel_groups  # noqa: F401 (the callers' argument for the compositing kernels)
from .vectors import _lane_dots, _lane_dots_into, _lane_sums_into, _lanes_axpy, _lanes_scale

LANES_REVISION = 27
"""Raised with every change to :mod:`.lanes` or :mod:`.vectors`: numba's cache (``cache=True``) checks only the time
stamp and size of the file that defines a kernel, and the block helpers are compiled into these kernels, so a change
to lanes.py, vectors.py or simd.py alone would leave a checkout that compiled them before with stale kernels (5: the
exponential in fused multiply-adds; 6: the blocks' own lists, the lane maximum; 7: one record a Gaussian; 8: the
blocks' walk in one helper; 9: the records prefetched; 10: the features too; 11: no channels, no copy; 12: the
prefetch in one helper; 13: the lanes' sums, maxima and channel updates as vector halves; 14: records on a cache
line; 15: the backward's marked entries; 16: a pair's sums side by side, the vector operations in their own
module; 17: their loads and stores shared; 18: selects, not branches; 19: sums added into the pairs' rows;
20: the rows' loads shared; 21: the records filled by a kernel of their own, for the caller; 22: the walks' state
as vectors, :mod:`.simd`, which this covers too; 23: whole records copied as vectors; 24: the blocks' entries
as bits of 64-entry words; 25: back to the lists; 26: the projection's columns and SH sums, whose kernels
:mod:`.projection_kernels` raises its own ``VECTORS_REVISION`` for; 27: one splat helper for the lanes'
broadcasts)."""


@nb.njit(inline="always")
def _blend(alpha, inside, Tp, kt):  # pragma: no cover - compiled
    """One pixel of a forward walk blending a Gaussian of value ``alpha`` (``inside``: the pixel lies in its
    footprint box) over the transmittance ``Tp`` (negative: the pixel has stopped): (the weight ``alpha Tp`` or 0, the
    transmittance after, whether it blended). A pixel whose transmittance would fall under ``TRANSMITTANCE_MIN``
    stops there without blending it, its transmittance negated."""
    zero = kt[7]
    ok = (alpha >= kt[0]) & (Tp > zero) & inside
    tn = Tp * (kt[6] - alpha)
    blend = ok & (tn >= kt[2])
    stop = ok & (tn < kt[2])
    return _pick(blend, alpha * Tp, zero), _pick(blend, tn, _pick(stop, -Tp, Tp)), blend


@nb.njit(parallel=True, cache=True, nogil=True)
def composite_forward(lists, starts, counts, busy, rec, colors, groups, width, height, tile, workers, out, t_final,
                      last, top, marks):  # pragma: no cover - compiled
    """Composite every busy tile front to back, one 4x4 block of pixels at a time.

    ``rec`` [N, 16]: the Gaussians' records (:func:`~.lanes.fill_records`, with the channels when ``C`` <= 4; the
    compositing's dtype); ``colors`` [N, C] the channels blended. Writes ``out`` [H, W, C] (colours without the
    background), ``t_final`` [H, W] (transmittance after the last blended Gaussian), ``last`` [H, W] (how many
    entries of the tile's run the pixel walked up to and including its last blended Gaussian: the backward starts
    there) and, when ``top`` is [H, W] rather than empty, the id of each
    pixel's largest-weight Gaussian (-1 where none). Pixels of tiles with no Gaussian are left as they are (the
    caller initialises ``out`` to 0, ``t_final`` to 1, ``last`` to 0 and ``top`` to -1). When ``marks`` is
    [M, words] uint64 (zeroed; ``words`` 64-bit words for the tile's blocks) rather than empty, sets bit ``k`` of pair
    ``j``'s row where the pair's Gaussian blended at least one pixel of the tile's block ``k``: the backward walks
    only those (:func:`composite_backward`). ``groups``: :func:`channel_groups` of ``C``.

    Each block walks the entries of the tile's run whose footprint box touches it, in run order, with its 16 pixels'
    state (transmittance, walked count, largest weight, channel sums) in vectors (:mod:`.simd`); every Gaussian is
    evaluated on all 16 pixels without branches, and counts only at those inside its footprint box (as if only the
    box's pixels were visited; pixels outside the tile or image start stopped). A
    stopped pixel keeps its transmittance negated. The tile's Gaussians are copied next to each other, 64 at a time,
    as the first block that has walked all its entries so far needs more, and each copied entry is appended to the
    lists of the blocks it touches; the other blocks read them in order.
    """
    C = colors.shape[1]
    NC = 4 * len(groups)
    tiles_x = (width + tile - 1) // tile
    nbx = (tile + 3) // 4
    want_top = top.shape[0] > 0
    want_marks = marks.shape[0] > 0
    kc = _constants(rec)
    kt = _constant_tuple(kc)
    a_max, half, one, zero = kc[1], kc[5], kc[6], kc[7]
    cap = _longest(busy, counts)
    for w in nb.prange(workers):
        geo = np.empty((cap, 16), kc.dtype)
        box = np.empty((cap, 4), np.int32)
        gid = np.empty(cap, np.int32)
        colp = np.empty((cap if NC > 4 else 1, NC), kc.dtype)  # four channels: in the records (geo)
        acc = nb.carray(_stack_empty(groups, kc.dtype), (NC, LANES))  # the block's channel sums
        pxc = _lanes(kc)
        pyc = _lanes(kc)
        T = _lanes(kc)
        W = _lanes(kc)
        L = _lanes(gid)
        bid = _lanes(gid)
        blist = np.empty((nbx * nbx, cap), np.int32)
        bcount = np.zeros(nbx * nbx, np.int64)
        for k in range(w, busy.shape[0], workers):
            t = busy[k]
            x_lo, y_lo, x_hi, y_hi = _tile_box(t, tiles_x, tile, width, height)
            s = starts[t]
            n = counts[t]
            packed = 0
            bcount[:] = 0
            for blk in range(nbx * nbx):
                bx = x_lo + 4 * (blk % nbx)
                by = y_lo + 4 * (blk // nbx)
                if bx > x_hi or by > y_hi:
                    continue
                _start_block(bx, by, x_hi, y_hi, pxc, pyc, T, one)
                word, bit, none = blk >> 6, np.uint64(1) << np.uint64(blk & 63), np.uint64(0)
                # the block's state as vectors (:mod:`.simd`): in registers from one entry to the next
                pxv, pyv, tv = simd.load(pxc, 0), simd.load(pyc, 0), simd.load(T, 0)
                lv, bidv = simd.splat(np.int32(0)), simd.splat(np.int32(-1))
                bestv = acc0v = acc1v = acc2v = acc3v = simd.splat(zero)
                for i in range(NC if NC > 4 else 0):
                    for q in range(LANES):
                        acc[i, q] = zero
                p = 0
                while True:
                    j1, packed = _next_entry(blk, p, packed, lists, s, n, rec, colors, geo, box, gid, colp, x_lo,
                                             y_lo, nbx, blist, bcount)
                    if j1 < 0:
                        break
                    p += 1
                    mx1, my1, a1, b1, c1, o1, x01, x11, y01, y11 = _geometry(geo, j1)
                    alpha1 = min(a_max, o1 * _gauss(pxv - mx1, pyv - my1, half * a1, b1, half * c1, kt))
                    in1 = (pxv > x01) & (pxv < x11) & (pyv > y01) & (pyv < y11)  # the footprint box
                    w1, tv, blend1 = _blend(alpha1, in1, tv, kt)
                    lv = _pick(blend1, np.int32(j1 + 1), lv)
                    if want_top:  # (a branch the CPU predicts: the same every entry)
                        better1 = w1 > bestv
                        bestv = _pick(better1, w1, bestv)
                        bidv = _pick(better1, gid[j1], bidv)
                    if NC == 4:  # four channels in the walk (a constant: no branch), by fused multiply-adds (1.09x)
                        acc0v = _fma(w1, geo[j1, 10], acc0v)
                        acc1v = _fma(w1, geo[j1, 11], acc1v)
                        acc2v = _fma(w1, geo[j1, 12], acc2v)
                        acc3v = _fma(w1, geo[j1, 13], acc3v)
                    else:
                        simd.store(W, 0, w1)
                        for i in range(NC):  # a channel's 16 pixels: two vectors of 8
                            _lanes_axpy(acc[i], W, colp[j1, i])
                    if want_marks:  # a select, not a branch: about one entry in five blends nowhere in a block
                        marks[s + j1, word] |= bit if simd.any_lane(blend1) else none
                    if not simd.any_lane(tv > zero):  # a block's pixels stop together
                        break
                simd.store(T, 0, tv)
                simd.store(L, 0, lv)
                simd.store(bid, 0, bidv)
                if NC == 4:  # rgb + depth out of the walk's vectors
                    simd.store(acc[0], 0, acc0v)
                    simd.store(acc[1], 0, acc1v)
                    simd.store(acc[2], 0, acc2v)
                    simd.store(acc[3], 0, acc3v)
                for q in range(LANES):
                    px = bx + (q & 3)
                    py = by + (q >> 2)
                    if px <= x_hi and py <= y_hi:
                        for ch in range(C):
                            out[py, px, ch] = acc[ch, q]
                        t_final[py, px] = abs(T[q])
                        last[py, px] = L[q]
                        if want_top:
                            top[py, px] = bid[q]


@nb.njit(inline="always")
def _recover(pxc, pyc, mx, my, ha, b, hc, o, x0, x1, y0, y1, walked, Tq, kt):  # pragma: no cover - compiled
    """A block's pixels in a backward walk (:class:`~.simd.Vec` values, or one pixel's scalars): (dx, dy, the
    Gaussian's value, the unclamped alpha, alpha, whether the pixel blended this Gaussian, 1 - alpha, the
    transmittance before it), with the forward's expression for alpha (bit for bit: the same pixels blend the same
    Gaussians). ``walked``: the entry lies before the pixel's last blended one;
    ``Tq``: the transmittance behind the entry. Where the pixel did not blend the entry, the transmittance before it
    is ``Tq`` itself (divided by 1, where a select of the lane's own value had compiled to a masked store that the
    next entry's load of the lane waited on, when the lanes were stack arrays)."""
    dx = pxc - mx
    dy = pyc - my
    gauss = _gauss(dx, dy, ha, b, hc, kt)
    raw = o * gauss
    alpha = min(kt[1], raw)
    inside = (pxc > x0) & (pxc < x1) & (pyc > y0) & (pyc < y1)
    act = walked & (alpha >= kt[0]) & inside
    one_minus = kt[6] - alpha
    return dx, dy, gauss, raw, alpha, act, one_minus, Tq / _pick(act, one_minus, kt[6])


@nb.njit(parallel=True, cache=True, nogil=True)
def composite_backward(lists, starts, counts, busy, rec, colors, groups, width, height, tile, workers, t_final, last,
                       marks, grad_out, grad_alpha, background, pair_geom, pair_colors,
                       geometry):  # pragma: no cover - compiled
    """Write each (tile, Gaussian) pair's gradient, summed over the tile's pixels walked back to front.

    Args (beyond the forward's, ``rec`` the forward's records):
        t_final, last: the forward's outputs. [H, W]
        marks: the forward's marks of the blocks each pair blended in. [M, words]
        grad_out: dL/d(colour image before the background). [H, W, C]
        grad_alpha: dL/d(alpha image). [H, W]
        background: the background per channel (0 for depth and features). [C]
        pair_geom: per pair of ``lists``, the gradient of (mx, my, conic a, b, c, opacity) (written: the rows of a
            busy tile's pairs are zeroed before its blocks add into them; ``lists`` holds no other pair). [M, 6]
        pair_colors: per pair, the gradient of the colours (written likewise). [M, C]
        geometry: whether to compute ``pair_geom`` (False when only colours or features are trained).
        groups: :func:`channel_groups` of ``C``.

    The tile's 4x4 blocks are walked one after the other, each through the entries the forward marked as blended in it
    (:func:`~.lanes._pack_marked`), back to front, with the forward's expression for every alpha (so the same pixels
    blend the same Gaussians; an entry blends in a pixel whose ``last`` lies past it); a pair's gradient is the sum of
    its 16 lanes in a fixed tree order, added block after block (an entry that blended nowhere in a block adds nothing
    there, so skipping it changes no value). :func:`reduce_pairs` then sums the pairs per Gaussian in list order: the
    result does not depend on the number of workers.

    With ``T_i`` the transmittance before Gaussian ``i`` and ``S_i`` the sum over the Gaussians behind it of
    ``w_j (c_j . g)``: ``dL/dc_i = alpha_i T_i g``, ``dL/dalpha_i = T_i (c_i . g) - (S_i + T_final (bg . g -
    g_alpha)) / (1 - alpha_i)``; alpha clamped at 0.99 passes no gradient to the opacity and the footprint.
    """
    C = colors.shape[1]
    NC = 4 * len(groups)
    tiles_x = (width + tile - 1) // tile
    nbx = (tile + 3) // 4
    if marks.shape[0] != lists.shape[0] or 64 * marks.shape[1] < nbx * nbx:
        raise ValueError("composite_backward needs the forward's marks: a row of words for each pair")
    kc = _constants(rec)
    kt = _constant_tuple(kc)
    a_max, half, one, zero = kc[1], kc[5], kc[6], kc[7]
    cap = _longest(busy, counts)
    for w in nb.prange(workers):
        geo = np.empty((cap, 16), kc.dtype)
        run = np.empty(cap, np.int32)  # each slot's place in the tile's run
        colp = np.empty((cap if NC > 4 else 1, NC), kc.dtype)  # four channels: in the records (geo)
        gpix = nb.carray(_stack_empty(groups, kc.dtype), (NC, LANES))  # dL/d(channel) of the block's pixels
        pxc = _lanes(kc)
        pyc = _lanes(kc)
        T = _lanes(kc)
        tail = _lanes(kc)
        CG = _lanes(kc)
        sums = nb.carray(_stack_empty(groups, kc.dtype), (NC * LANES,))  # a pair's channel sums (C < NC)
        L = _lanes(run)
        blist = np.empty((nbx * nbx, cap), np.int32)
        bcount = np.zeros(nbx * nbx, np.int64)
        for k in range(w, busy.shape[0], workers):
            t = busy[k]
            x_lo, y_lo, x_hi, y_hi = _tile_box(t, tiles_x, tile, width, height)
            s = starts[t]
            pair_colors[s:s + counts[t]] = zero  # the tile's pairs' rows, zeroed here (in parallel, then in cache)
            if geometry:
                pair_geom[s:s + counts[t]] = zero
            bcount[:] = 0
            _pack_marked(lists, s, counts[t], marks, rec, colors, geo, colp, run, blist, bcount)
            for blk in range(nbx * nbx):
                bx = x_lo + 4 * (blk % nbx)
                by = y_lo + 4 * (blk // nbx)
                if bcount[blk] == 0:  # nothing blended here (or the block lies past the image)
                    continue
                for q in range(LANES):
                    px = bx + (q & 3)
                    py = by + (q >> 2)
                    pxc[q] = px + 0.5
                    pyc[q] = py + 0.5
                    for i in range(NC):
                        gpix[i, q] = zero
                    if px <= x_hi and py <= y_hi:
                        tf = t_final[py, px]
                        T[q] = tf
                        bg_dot = 0.0
                        for ch in range(C):
                            gv = grad_out[py, px, ch]
                            gpix[ch, q] = gv
                            bg_dot += background[ch] * gv
                        tail[q] = tf * (bg_dot - grad_alpha[py, px])
                        L[q] = last[py, px]
                    else:
                        T[q] = one
                        tail[q] = zero
                        L[q] = 0
                # the block's state as vectors (:mod:`.simd`): in registers from one entry to the next
                pxv, pyv, tv, lv = simd.load(pxc, 0), simd.load(pyc, 0), simd.load(T, 0), simd.load(L, 0)
                tailv, sv = simd.load(tail, 0), simd.splat(zero)
                gv = (simd.load(gpix[0], 0), simd.load(gpix[1], 0), simd.load(gpix[2], 0), simd.load(gpix[3], 0))
                for pp in range(bcount[blk] - 1, -1, -1):
                    slot = blist[blk, pp]
                    jj = run[slot]
                    mx, my, a, b, c, o, x0, x1, y0, y1 = _geometry(geo, slot)
                    dx, dy, gauss, raw, alpha, act, one_minus, tv = _recover(
                        pxv, pyv, mx, my, half * a, b, half * c, o, x0, x1, y0, y1, jj < lv, tv, kt)
                    wt = _pick(act, alpha * tv, zero)
                    j = s + jj
                    if geometry:
                        if NC == 4:  # c_i . g: the alpha's gradient needs it
                            cg = gv[0] * geo[slot, 10]
                            cg = cg + gv[1] * geo[slot, 11]
                            cg = cg + gv[2] * geo[slot, 12]
                            cg = cg + gv[3] * geo[slot, 13]
                        else:
                            _lanes_scale(CG, gpix[0], colp[slot, 0])
                            for i in range(1, NC):
                                _lanes_axpy(CG, gpix[i], colp[slot, i])
                            cg = simd.load(CG, 0)
                        d_alpha = tv * cg - (sv + tailv) / one_minus
                        sv = sv + wt * cg
                        d_sigma = -d_alpha * alpha
                        on = act & (raw < a_max)  # alpha clamped at 0.99 passes no gradient
                        _lane_sums_into((_pick(on, -(d_sigma * (a * dx + b * dy)), zero),
                                         _pick(on, -(d_sigma * (c * dy + b * dx)), zero),
                                         _pick(on, d_sigma * half * dx * dx, zero),
                                         _pick(on, d_sigma * dx * dy, zero),
                                         _pick(on, d_sigma * half * dy * dy, zero),
                                         _pick(on, d_alpha * gauss, zero)), 6, pair_geom, j)
                    if NC == 4 and C == NC:  # each channel's 16 pixels, the channels side by side, into the row
                        _lane_dots_into(wt, gv, 4, pair_colors, j)
                    elif C == NC:
                        _lane_dots_into(wt, gpix, groups, pair_colors, j)
                    else:
                        _lane_dots(wt, gpix, groups, sums)
                        for i in range(C):
                            pair_colors[j, i] += sums[i]


@nb.njit(parallel=True, cache=True, nogil=True)
def composite_pairs(lists, starts, counts, busy, rec, width, height, tile, workers, offsets, pixels, ids,
                    weights):  # pragma: no cover - compiled
    """List every blended (pixel, Gaussian, weight ``alpha T``) of the view, walking the tiles' 4x4 blocks as the
    forward does (``rec``: the records without channels).

    With ``pixels`` empty, counts each busy tile's blended pairs into ``offsets[k + 1]`` and writes nothing else;
    otherwise ``offsets`` [B + 1] holds their cumulative sum and busy tile ``k``'s pairs are written into ``pixels``
    (row-major pixel index), ``ids`` and ``weights`` [M] from ``offsets[k]``.
    """
    tiles_x = (width + tile - 1) // tile
    nbx = (tile + 3) // 4
    fill = pixels.shape[0] > 0
    kc = _constants(rec)
    kt = _constant_tuple(kc)
    a_max, half, one, zero = kc[1], kc[5], kc[6], kc[7]
    cap = _longest(busy, counts)
    none = np.empty((1, 1), kc.dtype)  # no channels
    nocolp = np.empty((1, 0), kc.dtype)
    for w in nb.prange(workers):
        geo = np.empty((cap, 16), kc.dtype)
        box = np.empty((cap, 4), np.int32)
        gid = np.empty(cap, np.int32)
        blist = np.empty((nbx * nbx, cap), np.int32)
        bcount = np.zeros(nbx * nbx, np.int64)
        pxc = _lanes(kc)
        pyc = _lanes(kc)
        T = _lanes(kc)
        W = _lanes(kc)
        for k in range(w, busy.shape[0], workers):
            t = busy[k]
            x_lo, y_lo, x_hi, y_hi = _tile_box(t, tiles_x, tile, width, height)
            s, n = starts[t], counts[t]
            packed = n_pairs = 0
            base = offsets[k] if fill else 0  # where this tile's pairs go (read once: other workers write offsets)
            bcount[:] = 0
            for blk in range(nbx * nbx):
                bx = x_lo + 4 * (blk % nbx)
                by = y_lo + 4 * (blk // nbx)
                if bx > x_hi or by > y_hi:
                    continue
                _start_block(bx, by, x_hi, y_hi, pxc, pyc, T, one)
                pxv, pyv, tv = simd.load(pxc, 0), simd.load(pyc, 0), simd.load(T, 0)
                p = 0
                while True:
                    jj, packed = _next_entry(blk, p, packed, lists, s, n, rec, none, geo, box, gid, nocolp, x_lo,
                                             y_lo, nbx, blist, bcount)
                    if jj < 0:
                        break
                    p += 1
                    mx, my, a, b, c, o, x0, x1, y0, y1 = _geometry(geo, jj)
                    alpha = min(a_max, o * _gauss(pxv - mx, pyv - my, half * a, b, half * c, kt))  # as the forward
                    inside = (pxv > x0) & (pxv < x1) & (pyv > y0) & (pyv < y1)  # the footprint box
                    wv, tv, _ = _blend(alpha, inside, tv, kt)
                    if simd.any_lane(wv > zero):  # blended somewhere (alpha >= 1/255 and T >= 1e-4: a positive weight)
                        simd.store(W, 0, wv)
                        at = base + n_pairs
                        for q in range(LANES):
                            if W[q] > zero:
                                if fill:
                                    pixels[at] = (by + (q >> 2)) * width + bx + (q & 3)
                                    ids[at] = gid[jj]
                                    weights[at] = W[q]
                                at += 1
                        n_pairs = at - base
                    if not simd.any_lane(tv > zero):
                        break
            if not fill:
                offsets[k + 1] = n_pairs


@nb.njit(inline="always")
def _add_pair(out, lists, pair_values, j):  # pragma: no cover - compiled
    """Add pair ``j``'s values into its Gaussian's row of ``out``."""
    g = lists[j]
    for k in range(pair_values.shape[1]):
        out[g, k] += pair_values[j, k]


REDUCE_PREFETCH_BYTES = 4 << 20
"""Per-Gaussian sums larger than this are prefetched by :func:`reduce_pairs` (more than the two cores' L2 caches)."""
REDUCE_STRETCH = 4096
"""Pairs a worker of :func:`reduce_pairs` sorts out at a time (16 KB of ids)."""


@nb.njit(parallel=True, cache=True, nogil=True)
def reduce_pairs(lists, pair_values, out, workers):  # pragma: no cover - compiled
    """Write into ``out`` [n, K] the per-Gaussian sums of ``pair_values`` ``[M, K]`` (pair ``j`` belongs to Gaussian
    ``lists[j]``), added in pair order whatever the number of workers (each owns a range of Gaussians and zeroes its
    rows first: a serial memset before). ``out`` comes from the caller (numpy asks Linux for huge pages for large
    arrays, numba's own allocations fault 4 KB at a time: a quarter of a 650k-Gaussian features step was those faults,
    with the records').

    With several workers, each reads the pairs ``REDUCE_STRETCH`` at a time, writes the ids of those whose Gaussian is
    its own into a list without a branch (every id written, the count advanced by 0 or 1), then adds them. Each
    pair's Gaussian tested with a branch had made two workers slower than one where the Gaussians are listed in an
    order unrelated to the screen, as in people's files (100k Gaussians, 141k random pairs of six values: 0.85 ms
    against 0.63); now 0.78-0.95 ms there against 0.95-1.15 before, 3.9-6.5 ms against 12.0-12.9 for 1.2M random pairs
    of 500k Gaussians, and in frames of the benchmark scene shuffled 0.55-0.58 ms against 0.90-0.98 (100k, 256x256).
    The benchmark scene itself lists its Gaussians object by object: the branch was predicted there, and nothing
    changed (``benchmarks/RESULTS.md``, "Three leads that did not give")."""
    n, K = out.shape
    span = (n + workers - 1) // workers
    m = lists.shape[0]
    # sums beyond the caches: their rows asked for PREFETCH pairs ahead (500k Gaussians: 1.7-1.9x one thread, 1.1-1.3x
    # two; 300k 1.3x); sums that fit are not (100k Gaussians, 2.4 MB: 0.9x prefetched; 0.91-0.96x in a loop apart)
    far = n * K * pair_values.itemsize > REDUCE_PREFETCH_BYTES
    for w in nb.prange(workers):
        lo = min(n, w * span)
        hi = min(n, lo + span)
        out[lo:hi] = 0
        if workers == 1 and far:  # every pair
            for j in range(m):
                if j + PREFETCH < m:
                    _prefetch(out, np.int64(lists[j + PREFETCH]) * K)
                _add_pair(out, lists, pair_values, j)
            continue
        if workers == 1:
            for j in range(m):
                _add_pair(out, lists, pair_values, j)
            continue
        mine = np.empty(REDUCE_STRETCH, np.int32)
        for first in range(0, m, REDUCE_STRETCH):
            count = 0
            for j in range(first, min(m, first + REDUCE_STRETCH)):
                g = lists[j]
                mine[count] = j
                count += np.int64(g >= lo) & np.int64(g < hi)
            for p in range(count):
                if far and p + PREFETCH < count:
                    _prefetch(out, np.int64(lists[mine[p + PREFETCH]]) * K)
                _add_pair(out, lists, pair_values, mine[p])
