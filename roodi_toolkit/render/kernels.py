"""Compiled CPU kernels of the default renderer: footprints, tile binning, compositing forward and backward.

Numba's parallel JIT (installed as a wheel with LLVM inside: no compiler on the user's machine) compiles these loops
to native code on first use and caches the result beside this file (``cache=True``), so later processes start at
once. The arithmetic is that of :mod:`roodi_toolkit.render.rasterizer` (3DGS "classic" mode, the same footprints,
depth order, alpha clamp and cut-offs); :mod:`roodi_toolkit.render.fast` wraps these kernels as a differentiable
torch function and the tests compare both with the dense reference.

Layout: the image is cut into square tiles (at most 64 pixels wide: a tile row's stopped pixels are bits of an int64); each tile holds the depth-ordered run of the Gaussians whose footprint
touches it (``lists[starts[t]:starts[t] + counts[t]]``). A worker takes every ``workers``-th busy tile (interleaved,
so the busy parts of an image are shared out evenly) and walks the tile's run front to back (forward) or back to
front (backward), visiting only the pixels of each Gaussian's footprint box inside the tile. Results do not depend on
timing or on the number of workers: each tile is written by one worker, and the backward writes one gradient per
(tile, Gaussian) pair, which :func:`reduce_pairs` adds per Gaussian in pair order.

Per-pixel work is in float64 whatever the inputs' dtype, so float32 and float64 inputs composite alike. A
Gaussian's values along a row of its footprint box are computed first, in a loop without branches that LLVM
vectorises: ``exp(-sigma)`` there is ``(sum_{k<=10} u^k / k!)^16`` with ``u = -sigma / 16`` and sigma clamped to
``SIGMA_MAX`` (relative error below 1e-11, far under float32 rounding; forward and backward use the same values);
then the pixels of the row are composited in order. No fast-math flags: the values are IEEE arithmetic in a fixed order,
so the backward recomputes exactly the forward's alphas and takes exactly its decisions.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4
SIGMA_MAX = 6.0
"""Beyond this Mahalanobis half-square, ``opacity * exp(-sigma) < 1/255`` for any opacity: the alpha test drops the
pixel, so the Gaussian's value there is computed on ``SIGMA_MAX`` instead (keeps the polynomial in its range)."""
I3, I4, I5, I6, I7, I8, I9, I10 = (1.0 / math.factorial(k) for k in range(3, 11))  # Taylor coefficients of exp


@nb.njit(parallel=True, cache=True, nogil=True)
def footprints(means2d, cov_xx, cov_yy, opacities, usable, width, height, tile):  # pragma: no cover - compiled
    """Return (bounds [N, 4] int32 inclusive pixel box x0, x1, y0, y1; half [N, 2] int32 half-extents; tiles [N]
    int64 number of tiles touched, 0 where the Gaussian is not drawn).

    The footprint is the ellipse where ``opacity * G >= 1/255`` (Mahalanobis radius^2 ``2 ln(255 opacity)``), with a
    relative margin of 1e-6 so that pixels on its boundary are left to the alpha test.
    """
    n = means2d.shape[0]
    bounds = np.zeros((n, 4), np.int32)
    half = np.zeros((n, 2), np.int32)
    ntiles = np.zeros(n, np.int64)
    for i in nb.prange(n):
        o = np.float64(opacities[i])
        if not usable[i] or not o >= ALPHA_MIN:
            continue
        r2 = 2.0 * np.log(max(o * 255.0, 1.0)) * (1.0 + 1e-6)
        hx = np.sqrt(r2 * np.float64(cov_xx[i]))
        hy = np.sqrt(r2 * np.float64(cov_yy[i]))
        mx = np.float64(means2d[i, 0])
        my = np.float64(means2d[i, 1])
        if not (np.isfinite(mx) and np.isfinite(my) and np.isfinite(hx) and np.isfinite(hy)):
            continue
        x0 = np.ceil(mx - hx - 0.5)
        x1 = np.floor(mx + hx - 0.5)
        y0 = np.ceil(my - hy - 0.5)
        y1 = np.floor(my + hy - 0.5)
        if x0 > x1 or y0 > y1 or x1 < 0 or y1 < 0 or x0 > width - 1 or y0 > height - 1:
            continue
        ix0 = int(max(x0, 0.0))
        ix1 = int(min(x1, width - 1.0))
        iy0 = int(max(y0, 0.0))
        iy1 = int(min(y1, height - 1.0))
        bounds[i, 0] = ix0
        bounds[i, 1] = ix1
        bounds[i, 2] = iy0
        bounds[i, 3] = iy1
        half[i, 0] = int(np.ceil(hx))
        half[i, 1] = int(np.ceil(hy))
        ntiles[i] = (ix1 // tile - ix0 // tile + 1) * (iy1 // tile - iy0 // tile + 1)
    return bounds, half, ntiles


@nb.njit(cache=True, nogil=True)
def depth_order(ntiles, depths):  # pragma: no cover - compiled
    """Return the ids ``[D]`` int64 of the drawn Gaussians (``ntiles > 0``) by increasing depth, ties in id order:
    what ``argsort(kind="stable")`` gives, by a two-pass radix sort of the depths' float32 bit patterns (ordered
    as unsigned integers once negative ones are flipped); it works in time linear in ``D``."""
    n = ntiles.shape[0]
    count = 0
    for i in range(n):
        if ntiles[i] > 0:
            count += 1
    ids = np.empty(count, np.int64)
    keys = np.empty(count, np.uint32)
    k = 0
    for i in range(n):
        if ntiles[i] > 0:
            bits = np.array([np.float32(depths[i])]).view(np.uint32)[0]
            keys[k] = bits ^ (np.uint32(0xFFFFFFFF) if bits >> 31 else np.uint32(0x80000000))
            ids[k] = i
            k += 1
    tmp_ids = np.empty(count, np.int64)
    tmp_keys = np.empty(count, np.uint32)
    for shift in (0, 16):
        hist = np.zeros(65537, np.int64)
        for j in range(count):
            hist[((keys[j] >> shift) & 0xFFFF) + 1] += 1
        for d in range(65536):
            hist[d + 1] += hist[d]
        for j in range(count):
            d = (keys[j] >> shift) & 0xFFFF
            tmp_keys[hist[d]] = keys[j]
            tmp_ids[hist[d]] = ids[j]
            hist[d] += 1
        keys, tmp_keys = tmp_keys, keys
        ids, tmp_ids = tmp_ids, ids
    return ids


@nb.njit(parallel=True, cache=True, nogil=True)
def bin_tiles(order, bounds, width, height, tile, workers):  # pragma: no cover - compiled
    """Return (lists [M] int32 Gaussian ids grouped by tile in ``order``'s order, starts [T] int64, counts [T]
    int64) for the Gaussians ``order`` (depth-sorted ids of drawn Gaussians): a counting sort by tile, stable, so
    every tile's run stays in depth order. Each worker counts and places a contiguous stretch of ``order``; a tile's
    entries from an earlier stretch come first, so the result does not depend on the number of workers."""
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    T = tiles_x * tiles_y
    n = order.shape[0]
    span = (n + workers - 1) // workers
    per = np.zeros((workers, T), np.int64)
    for w in nb.prange(workers):
        for k in range(w * span, min(n, (w + 1) * span)):
            g = order[k]
            for ty in range(bounds[g, 2] // tile, bounds[g, 3] // tile + 1):
                for tx in range(bounds[g, 0] // tile, bounds[g, 1] // tile + 1):
                    per[w, ty * tiles_x + tx] += 1
    counts = np.zeros(T, np.int64)
    starts = np.zeros(T, np.int64)
    total = 0
    for t in range(T):
        starts[t] = total
        for w in range(workers):
            c = per[w, t]
            per[w, t] = total  # becomes the worker's cursor in this tile
            total += c
        counts[t] = total - starts[t]
    lists = np.empty(total, np.int32)
    for w in nb.prange(workers):
        for k in range(w * span, min(n, (w + 1) * span)):
            g = order[k]
            for ty in range(bounds[g, 2] // tile, bounds[g, 3] // tile + 1):
                for tx in range(bounds[g, 0] // tile, bounds[g, 1] // tile + 1):
                    t = ty * tiles_x + tx
                    lists[per[w, t]] = g
                    per[w, t] += 1
    return lists, starts, counts


@nb.njit(parallel=True, cache=True, nogil=True)
def composite_forward(lists, starts, counts, busy, bounds, means2d, conics, opacities, colors, width, height, tile,
                      workers, out, t_final, last, top):  # pragma: no cover - compiled
    """Composite every busy tile front to back.

    Writes ``out`` [H, W, C] (colours without the background), ``t_final`` [H, W] (transmittance after the last
    blended Gaussian), ``last`` [H, W] (how many entries of the tile's run the pixel walked up to and including its
    last blended Gaussian: the backward starts there) and, when ``top`` is [H, W] rather than empty, the id of each
    pixel's largest-weight Gaussian (-1 where none). Pixels of tiles with no Gaussian are left as they are (the
    caller initialises ``out`` to 0, ``t_final`` to 1, ``last`` to 0 and ``top`` to -1).
    """
    C = colors.shape[1]
    tiles_x = (width + tile - 1) // tile
    P = tile * tile
    want_top = top.shape[0] > 0
    for w in nb.prange(workers):
        T = np.empty(P)
        acc = np.empty((P, C))
        lst = np.empty(P, np.int32)
        done = np.empty(P, np.bool_)
        best = np.empty(P)
        best_id = np.empty(P, np.int32)
        col = np.empty(C)
        row_alpha = np.empty(tile)
        done_rows = np.empty(tile, np.int64)
        for k in range(w, busy.shape[0], workers):
            t = busy[k]
            x_lo = (t % tiles_x) * tile
            y_lo = (t // tiles_x) * tile
            x_hi = min(x_lo + tile, width) - 1
            y_hi = min(y_lo + tile, height) - 1
            T[:] = 1.0
            acc[:] = 0.0
            lst[:] = 0
            done[:] = False
            done_rows[:] = 0
            best[:] = 0.0
            best_id[:] = -1
            remaining = (x_hi - x_lo + 1) * (y_hi - y_lo + 1)
            s = starts[t]
            for j in range(s, s + counts[t]):
                g = lists[j]
                mx = np.float64(means2d[g, 0])
                my = np.float64(means2d[g, 1])
                a = np.float64(conics[g, 0])
                b = np.float64(conics[g, 1])
                c = np.float64(conics[g, 2])
                o = np.float64(opacities[g])
                for ch in range(C):
                    col[ch] = colors[g, ch]
                x0 = max(bounds[g, 0], x_lo)
                nx = min(bounds[g, 1], x_hi) - x0 + 1
                dx0 = x0 + 0.5 - mx
                cols = ((1 << nx) - 1) << (x0 - x_lo)  # the box's columns as bits of a tile row
                for py in range(max(bounds[g, 2], y_lo), min(bounds[g, 3], y_hi) + 1):
                    if done_rows[py - y_lo] & cols == cols:  # every pixel of the box in this row has stopped
                        continue
                    dy = py + 0.5 - my
                    cdy = 0.5 * c * dy * dy
                    bdy = b * dy
                    for q in range(nx):  # the row's Gaussian values, vectorised
                        dx = dx0 + q
                        u = -0.0625 * min(0.5 * a * dx * dx + bdy * dx + cdy, SIGMA_MAX)
                        e = 1.0 + u * (1.0 + u * (0.5 + u * (I3 + u * (I4 + u * (I5 + u * (I6 + u * (I7 + u * (
                            I8 + u * (I9 + u * I10)))))))))
                        e *= e
                        e *= e
                        e *= e
                        row_alpha[q] = min(ALPHA_MAX, o * (e * e))
                    base = (py - y_lo) * tile + x0 - x_lo
                    for q in range(nx):
                        p = base + q
                        alpha = row_alpha[q]
                        if done[p] or alpha < ALPHA_MIN:
                            continue
                        t_next = T[p] * (1.0 - alpha)
                        if t_next < TRANSMITTANCE_MIN:
                            done[p] = True
                            done_rows[py - y_lo] |= 1 << (x0 - x_lo + q)
                            remaining -= 1
                            continue
                        weight = alpha * T[p]
                        for ch in range(C):
                            acc[p, ch] += weight * col[ch]
                        if want_top and weight > best[p]:
                            best[p] = weight
                            best_id[p] = g
                        T[p] = t_next
                        lst[p] = j - s + 1
                if remaining == 0:
                    break
            for py in range(y_lo, y_hi + 1):
                for px in range(x_lo, x_hi + 1):
                    p = (py - y_lo) * tile + px - x_lo
                    for ch in range(C):
                        out[py, px, ch] = acc[p, ch]
                    t_final[py, px] = T[p]
                    last[py, px] = lst[p]
                    if want_top:
                        top[py, px] = best_id[p]


@nb.njit(parallel=True, cache=True, nogil=True)
def composite_backward(lists, starts, counts, busy, bounds, means2d, conics, opacities, colors, width, height, tile,
                       workers, t_final, last, grad_out, grad_alpha, background, pair_geom, pair_colors,
                       geometry):  # pragma: no cover - compiled
    """Write each (tile, Gaussian) pair's gradient, summed over the tile's pixels walked back to front.

    Args (beyond the forward's):
        t_final, last: the forward's outputs. [H, W]
        grad_out: dL/d(colour image before the background). [H, W, C]
        grad_alpha: dL/d(alpha image). [H, W]
        background: the background per channel (0 for depth and features). [C]
        pair_geom: per pair of ``lists``, the gradient of (mx, my, conic a, b, c, opacity), zeroed. [M, 6]
        pair_colors: per pair, the gradient of the colours, zeroed. [M, C]
        geometry: whether to compute ``pair_geom`` (False when only colours or features are trained).

    :func:`reduce_pairs` then sums the pairs per Gaussian in list order: the result does not depend on the number of
    workers.

    With ``T_i`` the transmittance before Gaussian ``i`` and ``S_i`` the sum over the Gaussians behind it of
    ``w_j (c_j . g)``: ``dL/dc_i = alpha_i T_i g``, ``dL/dalpha_i = T_i (c_i . g) - (S_i + T_final (bg . g -
    g_alpha)) / (1 - alpha_i)``; alpha clamped at 0.99 passes no gradient to the opacity and the footprint.
    """
    C = colors.shape[1]
    tiles_x = (width + tile - 1) // tile
    P = tile * tile
    for w in nb.prange(workers):
        T = np.empty(P)
        S = np.empty(P)
        tail = np.empty(P)
        lst = np.empty(P, np.int32)
        gpix = np.zeros((P, C))
        gcol = np.empty(C)
        col = np.empty(C)
        row_gauss = np.empty(tile)
        row_last = np.empty(tile, np.int32)
        for k in range(w, busy.shape[0], workers):
            t = busy[k]
            x_lo = (t % tiles_x) * tile
            y_lo = (t // tiles_x) * tile
            x_hi = min(x_lo + tile, width) - 1
            y_hi = min(y_lo + tile, height) - 1
            deepest = 0
            lst[:] = 0
            row_last[:] = 0
            for py in range(y_lo, y_hi + 1):
                for px in range(x_lo, x_hi + 1):
                    p = (py - y_lo) * tile + px - x_lo
                    tf = np.float64(t_final[py, px])
                    T[p] = tf
                    S[p] = 0.0
                    bg_dot = 0.0
                    for ch in range(C):
                        gpix[p, ch] = grad_out[py, px, ch]
                        bg_dot += background[ch] * gpix[p, ch]
                    tail[p] = tf * (bg_dot - grad_alpha[py, px])
                    lst[p] = last[py, px]
                    row_last[py - y_lo] = max(row_last[py - y_lo], lst[p])
                    deepest = max(deepest, lst[p])
            s = starts[t]
            for j in range(s + deepest - 1, s - 1, -1):
                g = lists[j]
                jj = j - s
                mx = np.float64(means2d[g, 0])
                my = np.float64(means2d[g, 1])
                a = np.float64(conics[g, 0])
                b = np.float64(conics[g, 1])
                c = np.float64(conics[g, 2])
                o = np.float64(opacities[g])
                for ch in range(C):
                    col[ch] = colors[g, ch]
                gcol[:] = 0.0
                g_mx = 0.0
                g_my = 0.0
                g_a = 0.0
                g_b = 0.0
                g_c = 0.0
                g_o = 0.0
                hit = False
                x0 = max(bounds[g, 0], x_lo)
                nx = min(bounds[g, 1], x_hi) - x0 + 1
                dx0 = x0 + 0.5 - mx
                for py in range(max(bounds[g, 2], y_lo), min(bounds[g, 3], y_hi) + 1):
                    if jj >= row_last[py - y_lo]:  # no pixel of this row walked this far in the forward
                        continue
                    dy = py + 0.5 - my
                    cdy = 0.5 * c * dy * dy
                    bdy = b * dy
                    for q in range(nx):  # as the forward
                        dx = dx0 + q
                        u = -0.0625 * min(0.5 * a * dx * dx + bdy * dx + cdy, SIGMA_MAX)
                        e = 1.0 + u * (1.0 + u * (0.5 + u * (I3 + u * (I4 + u * (I5 + u * (I6 + u * (I7 + u * (
                            I8 + u * (I9 + u * I10)))))))))
                        e *= e
                        e *= e
                        e *= e
                        row_gauss[q] = e * e
                    base = (py - y_lo) * tile + x0 - x_lo
                    for q in range(nx):
                        p = base + q
                        if jj >= lst[p]:
                            continue
                        gauss = row_gauss[q]
                        raw = o * gauss  # as the forward's o * (e * e), bit for bit
                        alpha = min(ALPHA_MAX, raw)
                        if alpha < ALPHA_MIN:
                            continue
                        hit = True
                        one_minus = 1.0 - alpha
                        Ti = T[p] / one_minus
                        weight = alpha * Ti
                        T[p] = Ti
                        for ch in range(C):
                            gcol[ch] += weight * gpix[p, ch]
                        if not geometry:  # colours or features alone: no need for the alpha's gradient
                            continue
                        cg = 0.0
                        for ch in range(C):
                            cg += col[ch] * gpix[p, ch]
                        d_alpha = Ti * cg - (S[p] + tail[p]) / one_minus
                        S[p] += weight * cg
                        if raw < ALPHA_MAX:
                            dx = dx0 + q
                            g_o += d_alpha * gauss
                            d_sigma = -d_alpha * alpha
                            g_mx -= d_sigma * (a * dx + b * dy)
                            g_my -= d_sigma * (c * dy + b * dx)
                            g_a += d_sigma * 0.5 * dx * dx
                            g_b += d_sigma * dx * dy
                            g_c += d_sigma * 0.5 * dy * dy
                if hit:
                    for ch in range(C):
                        pair_colors[j, ch] = gcol[ch]
                    if geometry:
                        pair_geom[j, 0] = g_mx
                        pair_geom[j, 1] = g_my
                        pair_geom[j, 2] = g_a
                        pair_geom[j, 3] = g_b
                        pair_geom[j, 4] = g_c
                        pair_geom[j, 5] = g_o


@nb.njit(parallel=True, cache=True, nogil=True)
def reduce_pairs(lists, pair_values, n, workers):  # pragma: no cover - compiled
    """Return the per-Gaussian sums ``[n, K]`` of ``pair_values`` ``[M, K]`` (pair ``j`` belongs to Gaussian
    ``lists[j]``), added in pair order whatever the number of workers (each owns a range of Gaussians)."""
    K = pair_values.shape[1]
    out = np.zeros((n, K), pair_values.dtype)
    span = (n + workers - 1) // workers
    for w in nb.prange(workers):
        lo = w * span
        hi = min(n, lo + span)
        for j in range(lists.shape[0]):
            g = lists[j]
            if lo <= g < hi:
                for k in range(K):
                    out[g, k] += pair_values[j, k]
    return out


@nb.njit(parallel=True, cache=True, nogil=True)
def composite_pairs(lists, starts, counts, busy, bounds, means2d, conics, opacities, width, height, tile, workers,
                    offsets, pixels, ids, weights):  # pragma: no cover - compiled
    """List every blended (pixel, Gaussian, weight ``alpha T``) of the view, walking the tiles as the forward does.

    With ``pixels`` empty, counts each busy tile's blended pairs into ``offsets[k + 1]`` and writes nothing else;
    otherwise ``offsets`` [B + 1] holds their cumulative sum and busy tile ``k``'s pairs are written into ``pixels``
    (row-major pixel index), ``ids`` and ``weights`` [M] from ``offsets[k]``.
    """
    tiles_x = (width + tile - 1) // tile
    P = tile * tile
    fill = pixels.shape[0] > 0
    for w in nb.prange(workers):
        T = np.empty(P)
        done = np.empty(P, np.bool_)
        row_alpha = np.empty(tile)
        done_rows = np.empty(tile, np.int64)
        for k in range(w, busy.shape[0], workers):
            t = busy[k]
            x_lo = (t % tiles_x) * tile
            y_lo = (t // tiles_x) * tile
            x_hi = min(x_lo + tile, width) - 1
            y_hi = min(y_lo + tile, height) - 1
            T[:] = 1.0
            done[:] = False
            done_rows[:] = 0
            remaining = (x_hi - x_lo + 1) * (y_hi - y_lo + 1)
            n_pairs = 0
            s = starts[t]
            for j in range(s, s + counts[t]):
                g = lists[j]
                mx = np.float64(means2d[g, 0])
                my = np.float64(means2d[g, 1])
                a = np.float64(conics[g, 0])
                b = np.float64(conics[g, 1])
                c = np.float64(conics[g, 2])
                o = np.float64(opacities[g])
                x0 = max(bounds[g, 0], x_lo)
                nx = min(bounds[g, 1], x_hi) - x0 + 1
                dx0 = x0 + 0.5 - mx
                cols = ((1 << nx) - 1) << (x0 - x_lo)
                for py in range(max(bounds[g, 2], y_lo), min(bounds[g, 3], y_hi) + 1):
                    if done_rows[py - y_lo] & cols == cols:
                        continue
                    dy = py + 0.5 - my
                    cdy = 0.5 * c * dy * dy
                    bdy = b * dy
                    for q in range(nx):
                        dx = dx0 + q
                        u = -0.0625 * min(0.5 * a * dx * dx + bdy * dx + cdy, SIGMA_MAX)
                        e = 1.0 + u * (1.0 + u * (0.5 + u * (I3 + u * (I4 + u * (I5 + u * (I6 + u * (I7 + u * (
                            I8 + u * (I9 + u * I10)))))))))
                        e *= e
                        e *= e
                        e *= e
                        row_alpha[q] = min(ALPHA_MAX, o * (e * e))
                    base = (py - y_lo) * tile + x0 - x_lo
                    for q in range(nx):
                        p = base + q
                        alpha = row_alpha[q]
                        if done[p] or alpha < ALPHA_MIN:
                            continue
                        t_next = T[p] * (1.0 - alpha)
                        if t_next < TRANSMITTANCE_MIN:
                            done[p] = True
                            done_rows[py - y_lo] |= 1 << (x0 - x_lo + q)
                            remaining -= 1
                            continue
                        if fill:
                            at = offsets[k] + n_pairs
                            pixels[at] = py * width + x0 + q
                            ids[at] = g
                            weights[at] = alpha * T[p]
                        n_pairs += 1
                        T[p] = t_next
                if remaining == 0:
                    break
            if not fill:
                offsets[k + 1] = n_pairs
