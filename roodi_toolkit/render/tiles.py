"""Compiled CPU kernels of the default renderer that order a view's drawn Gaussians into its tiles' runs: the depth
order (a radix sort of the depths' bits) and the binning (a counting sort into tiles, each tile's run in depth order).

Split from :mod:`roodi_toolkit.render.kernels` (the compositing and the pairs' reduction), which walks these runs.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .lanes import PREFETCH, _prefetch  # compiled into these kernels: a change to it needs a change here too


RADIX_BITS = 13
"""The most bits of the depth keys each pass of :func:`depth_order` sorts by: the keys' span (the bits that differ
between the nearest and the farthest drawn Gaussian, about 25 for depths from 2 to 8) in as few passes as that allows,
of equal width: two passes of 8,192 buckets (64 KB of write cursors a worker: in the L2 cache) for 25 bits, where 11
bits made three passes of 512 (one thread 1.06-1.10x at 100k Gaussians, 1.11-1.17x at 500k; two threads within the
runs' noise) and 16 bits two passes of 65,536 (0.92x of three passes of 11)."""


@nb.njit(parallel=True, cache=True, nogil=True)
def depth_order(ntiles, depths, workers):  # pragma: no cover - compiled
    """Return the ids ``[D]`` int32 of the drawn Gaussians (``ntiles > 0``) by increasing depth, ties in id order:
    what ``argsort(kind="stable")`` gives, by a radix sort of the depths' float32 bit patterns (ordered as unsigned
    integers once negative ones are flipped, less the smallest), linear in ``D``. Each of ``workers`` counts and
    places a contiguous stretch in every pass, after the stretches before it (a stable counting sort), so the order
    does not depend on the number of workers. (Each key made from a one-value array, as before, was an allocation a
    Gaussian: half the sort's time. The keys' span instead of all 32 bits, and 32-bit ids: 1.3-1.4x.)"""
    n = ntiles.shape[0]
    span = (n + workers - 1) // workers
    drawn = np.zeros(workers + 1, np.int64)
    for w in nb.prange(workers):
        c = 0
        for i in range(w * span, min(n, (w + 1) * span)):
            if ntiles[i] > 0:
                c += 1
        drawn[w + 1] = c
    for w in range(workers):
        drawn[w + 1] += drawn[w]
    count = drawn[workers]
    ids = np.empty(count, np.int32)
    keys = np.empty(count, np.uint32)
    patterns = depths.astype(np.float32).view(np.uint32)  # a copy, even of float32 depths: its view is contiguous
    least = np.full(workers, np.uint32(0xFFFFFFFF))
    most = np.zeros(workers, np.uint32)
    for w in nb.prange(workers):
        k = drawn[w]
        lo = np.uint32(0xFFFFFFFF)
        hi = np.uint32(0)
        for i in range(w * span, min(n, (w + 1) * span)):
            if ntiles[i] > 0:
                bits = patterns[i]
                key = bits ^ (np.uint32(0xFFFFFFFF) if bits >> 31 else np.uint32(0x80000000))
                keys[k] = key
                lo = min(lo, key)
                hi = max(hi, key)
                ids[k] = i
                k += 1
        least[w] = lo
        most[w] = hi
    lo = least.min()
    width = 0  # the bits in which the keys differ from the smallest
    if count > 0:
        while width < 32 and ((most.max() - lo) >> np.uint32(width)) > 0:
            width += 1
    passes = max(1, (width + RADIX_BITS - 1) // RADIX_BITS)
    digit = max(1, (width + passes - 1) // passes)
    for k in nb.prange(count):
        keys[k] -= lo
    tmp_ids = np.empty(count, np.int32)
    tmp_keys = np.empty(count, np.uint32)
    buckets = 1 << digit
    mask = np.uint32(buckets - 1)
    cursor = np.empty((workers, buckets), np.int64)
    part = (count + workers - 1) // workers
    for pass_ in range(passes):
        shift = np.uint32(pass_ * digit)
        for w in nb.prange(workers):
            cursor[w, :] = 0
            for j in range(w * part, min(count, (w + 1) * part)):
                cursor[w, (keys[j] >> shift) & mask] += 1
        total = 0
        for d in range(buckets):  # bucket-major, worker-minor: the workers' cursors into the next pass's order
            for w in range(workers):
                c = cursor[w, d]
                cursor[w, d] = total
                total += c
        for w in nb.prange(workers):
            for j in range(w * part, min(count, (w + 1) * part)):
                d = (keys[j] >> shift) & mask
                at = cursor[w, d]
                tmp_keys[at] = keys[j]
                tmp_ids[at] = ids[j]
                cursor[w, d] = at + 1
        keys, tmp_keys = tmp_keys, keys
        ids, tmp_ids = tmp_ids, ids
    return ids


@nb.njit(parallel=True, cache=True, nogil=True)
def bin_tiles(order, bounds, width, height, tile, workers):  # pragma: no cover - compiled
    """Return (lists [M] int32 Gaussian ids grouped by tile in ``order``'s order, starts [T] int64, counts [T]
    int64) for the Gaussians ``order`` (depth-sorted ids of drawn Gaussians): a counting sort by tile, stable, so
    every tile's run stays in depth order. The tile ranges of the Gaussians are first gathered in ``order``'s order
    (one pass of random reads; the count and the placement then read them in sequence). Each worker counts and
    places a contiguous stretch of ``order``; a tile's entries from an earlier stretch come first, so the result
    does not depend on the number of workers."""
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    T = tiles_x * tiles_y
    n = order.shape[0]
    span = (n + workers - 1) // workers
    ranges = np.empty((n, 4), np.int32)  # tx0, tx1, ty0, ty1 in depth order
    shift = 0  # tiles of a power of two pixels: shifts, not four integer divisions a Gaussian
    while (1 << shift) < tile:
        shift += 1
    if (1 << shift) == tile:  # the footprints asked for PREFETCH ahead: their order is random in memory
        for w in nb.prange(workers):
            end = min(n, (w + 1) * span)
            for k in range(w * span, end):
                if k + PREFETCH < end:
                    _prefetch(bounds, np.int64(order[k + PREFETCH]) * 4)
                g = order[k]
                for c in range(4):
                    ranges[k, c] = bounds[g, c] >> shift
    else:
        for k in nb.prange(n):
            g = order[k]
            for c in range(4):
                ranges[k, c] = bounds[g, c] // tile
    per = np.zeros((workers, T), np.int64)
    for w in nb.prange(workers):
        for k in range(w * span, min(n, (w + 1) * span)):
            for ty in range(ranges[k, 2], ranges[k, 3] + 1):
                for tx in range(ranges[k, 0], ranges[k, 1] + 1):
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
            for ty in range(ranges[k, 2], ranges[k, 3] + 1):
                for tx in range(ranges[k, 0], ranges[k, 1] + 1):
                    t = ty * tiles_x + tx
                    lists[per[w, t]] = g
                    per[w, t] += 1
    return lists, starts, counts
