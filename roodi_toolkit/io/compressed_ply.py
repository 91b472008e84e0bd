"""PlayCanvas compressed PLY (``.compressed.ply``, SuperSplat and splat-transform).

Layout (as splat-transform 2.7.1 reads and writes it): a binary little-endian PLY with an element ``chunk`` (one row
per 256 Gaussians: float min/max of position, of log-scale and optionally of colour), an element ``vertex`` with four
``uint`` words per Gaussian (``packed_position`` 11/10/11 bits, ``packed_rotation`` 2-bit largest-component index +
3x10 bits, ``packed_scale`` 11/10/11 bits, ``packed_color`` 8/8/8/8 bits RGBA with alpha = sigmoid(opacity)) and an
optional element ``sh`` with the ``f_rest_*`` coefficients quantised to ``uchar``.

Decoding follows splat-transform's ``decompressPly`` value for value (including the ``uchar`` SH rule, where 0 and
255 map to the ends of [-4, 4]); encoding follows its ``CompressedChunk.pack`` (Morton order, chunk bounds, log-scale
bounds clamped to [-20, 20], round-half-up quantisation), so files written here read back in splat-transform and
SuperSplat with the same error as their own.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..gaussians import SH_C0, GaussianCloud
from .files import atomic_path
from .ply import PlyHeader

CHUNK = 256
"""Gaussians per chunk (fixed by the format)."""

_CHUNK_BOUNDS = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
                 "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z"]
_CHUNK_COLOUR = ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
_PACKED = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]
_SCALE_LIMIT = 20.0  # splat-transform clamps chunk log-scale bounds to +-20 ("sometimes values are at infinity")


def is_compressed(header: PlyHeader) -> bool:
    """Return whether a PLY header declares PlayCanvas's compressed layout (a chunk element and packed words)."""
    names = {el.name: [n for n, _ in el.properties] for el in header.elements}
    return "chunk" in names and "vertex" in names and all(p in names["vertex"] for p in _PACKED)


def _elements(p: Path, header: PlyHeader, file_size: int) -> dict[str, np.ndarray]:
    """Read every element of a binary little-endian PLY into a structured array, checking sizes first."""
    if header.format != "binary_little_endian":
        raise FormatError(f"{p}: compressed PLY must be binary_little_endian, this one is {header.format}")
    offset = header.size
    out = {}
    layout = []
    for el in header.elements:
        if any(t == "list" for _, t in el.properties):
            raise FormatError(f"{p}: element {el.name!r} has list properties; not a compressed PLY")
        dtype = np.dtype([(n, "<" + t) for n, t in el.properties])
        layout.append((el, dtype, offset))
        offset += dtype.itemsize * el.count
    if offset > file_size:
        raise FormatError(f"{p}: header declares {offset - header.size} bytes of data but the file holds "
                          f"{file_size - header.size}: truncated or corrupt")
    with open(p, "rb") as f:
        for el, dtype, start in layout:
            f.seek(start)
            out[el.name] = np.fromfile(f, dtype=dtype, count=el.count)
    return out


def read_compressed_ply(path: str | os.PathLike, header: PlyHeader) -> GaussianCloud:
    """Return the Gaussians of a PlayCanvas compressed PLY whose header has already been parsed.

    Opacity logits are decoded as splat-transform does, so alpha bytes 0 and 255 give -inf and +inf (the caller
    maps them to finite logits, see :mod:`roodi_toolkit.io.splat`).

    Raises:
        FormatError: missing chunk/vertex properties, a chunk count that does not match the vertex count, an SH
            element of the wrong size, or a truncated body.
    """
    p = Path(path)
    els = _elements(p, header, p.stat().st_size)
    chunk, vertex = els["chunk"], els["vertex"]
    missing = [n for n in _CHUNK_BOUNDS if n not in (chunk.dtype.names or ())]
    if missing:
        raise FormatError(f"{p}: compressed PLY chunk element lacks {missing}")
    n = len(vertex)
    if n == 0:
        raise FormatError(f"{p}: file declares 0 vertices: there are no Gaussians to read")
    if len(chunk) != -(-n // CHUNK):
        raise FormatError(f"{p}: {len(chunk)} chunks cannot hold {n} Gaussians (expected {-(-n // CHUNK)}): corrupt")
    rest, sh_bytes = np.zeros((n, 0, 3), dtype=np.float32), None
    if "sh" in els:
        sh = els["sh"]
        names = sorted(sh.dtype.names or (), key=lambda s: int(s[7:]) if s.startswith("f_rest_") else -1)
        if len(sh) != n or len(names) not in (9, 24, 45) or not all(s.startswith("f_rest_") for s in names):
            raise FormatError(f"{p}: compressed PLY 'sh' element must hold 9, 24 or 45 f_rest_* per Gaussian")
        per = len(names) // 3
        rest = np.empty((n, per, 3), dtype=np.float32)
        if list(sh.dtype.names) == names and all(sh.dtype[s] == np.uint8 for s in names):  # as written: uchar
            sh_bytes = sh.view(np.uint8).reshape(n, len(names))  # decoded with the blocks below
        else:
            for i, name in enumerate(names):  # channel-major in the file: coefficient i % per of channel i // per
                rest[:, i % per, i // per] = _sh_values(sh[name])
    means = np.empty((n, 3), dtype=np.float32)
    log_scales = np.empty((n, 3), dtype=np.float32)
    quats = np.empty((n, 4), dtype=np.float32)
    sh_dc = np.empty((n, 3), dtype=np.float32)
    opacity = np.empty(n, dtype=np.float32)

    def decode(c0: int) -> None:
        rows = slice(c0 * CHUNK, min(n, (c0 + BLOCK_CHUNKS) * CHUNK))
        _decode_block(chunk[c0:c0 + BLOCK_CHUNKS], vertex[rows], means[rows], log_scales[rows], quats[rows],
                      sh_dc[rows], opacity[rows])
        if sh_bytes is not None:
            per = rest.shape[1]
            for c in range(3):  # channel-major in the file: the bytes of channel c are coefficients 0..per-1
                rest[rows, :, c] = np.take(_SH_BYTES, sh_bytes[rows, c * per:(c + 1) * per])

    starts = range(0, len(chunk), BLOCK_CHUNKS)
    workers = min(decode_threads(), len(starts))
    if workers > 1:  # NumPy's loops release the GIL: blocks decode in parallel, each into its own output rows
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(decode, starts))
    else:
        for c0 in starts:
            decode(c0)
    return GaussianCloud(means=means, quats_wxyz=quats, log_scales=log_scales, opacity_logits=opacity,
                         sh_dc=sh_dc, sh_rest=rest)


def _sh_values(raw: np.ndarray) -> np.ndarray:
    """Return the SH coefficients (float64, as splat-transform computes them) of the file's SH bytes."""
    raw = raw.astype(np.float64)
    unit = np.where(raw == 0, 0.0, np.where(raw == 255, 1.0, (raw + 0.5) / 256.0))
    return (unit - 0.5) * 8.0


_SH_BYTES = _sh_values(np.arange(256)).astype(np.float32)
"""The coefficient of each SH byte, looked up instead of computed per value (the same float32 values)."""


BLOCK_CHUNKS = 256
"""Chunks decoded together (65,536 Gaussians): a block's float64 temporaries stay near the cache, and the blocks are
shared among threads (:func:`decode_threads`). Measured on 1,069,222 Gaussians (the biker seven times, SH degree 0;
2-core machine, best of 7): the whole file at once 0.156 s; in blocks of 64 chunks 0.096 s, 256 chunks 0.103 s; with
two threads, blocks of 64 / 128 / 256 / 512 chunks 0.090 / 0.071 / 0.063 / 0.074 s. Reading the same cloud as plain
PLY takes 0.04-0.05 s."""


def decode_threads() -> int:
    """Threads that decode a compressed PLY: the usable cores, at most 4, and at most ``$OMP_NUM_THREADS`` when set
    (batch workers set it to 1: they already run one per core)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        limit = int(os.environ.get("OMP_NUM_THREADS", "") or cores)
    except ValueError:
        limit = cores
    return max(1, min(4, cores, limit))


with np.errstate(divide="ignore"):
    _LOGIT = (-np.log(1.0 / (np.arange(256) / 255.0) - 1.0)).astype(np.float32)
"""The opacity logit of each alpha byte, as the reference computes it (float64, then stored as float32)."""


def _decode_block(chunk: np.ndarray, vertex: np.ndarray, means: np.ndarray, log_scales: np.ndarray,
                  quats: np.ndarray, sh_dc: np.ndarray, opacity: np.ndarray) -> None:
    """Decode the packed words of ``vertex`` (the rows of the chunks ``chunk``) into the output rows given.

    Chunk by chunk with broadcasting ([chunks, 256] words against [chunks, 1] bounds): no per-row gather of the
    bounds. float64 as splat-transform (JavaScript numbers), so the values are the reference's.
    """
    n, n_chunks = len(vertex), len(chunk)
    bound = {name: chunk[name].astype(np.float64)[:, None] for name in chunk.dtype.names}

    def words(name: str) -> np.ndarray:
        w = np.zeros(n_chunks * CHUNK, dtype=np.uint32)
        w[:n] = vertex[name]
        return w.reshape(n_chunks, CHUNK)

    def lerp_into(out: np.ndarray, lo: str, hi: str, t: np.ndarray) -> None:
        out[:] = (bound[lo] * (1.0 - t) + bound[hi] * t).reshape(-1)[:n]

    for out, key, names in ((means, "packed_position", ("x", "y", "z")),
                            (log_scales, "packed_scale", ("scale_x", "scale_y", "scale_z"))):
        w = words(key)
        for k, (shift, mask) in enumerate(((21, 2047), (11, 1023), (0, 2047))):
            t = ((w >> shift) & mask) / float(mask)
            lerp_into(out[:, k], f"min_{names[k]}", f"max_{names[k]}", t)

    rot = vertex["packed_rotation"].astype(np.uint32)
    norm = np.sqrt(2.0)  # splat-transform: 1 / (sqrt(2) * 0.5)
    abc = [(((rot >> s) & 1023) / 1023.0 - 0.5) * norm for s in (20, 10, 0)]
    m = np.sqrt(np.maximum(0.0, 1.0 - (abc[0] * abc[0] + abc[1] * abc[1] + abc[2] * abc[2])))
    which = rot >> 30
    # the three stored components fill, in order, the slots other than the largest one
    for j in range(4):
        below = abc[j] if j < 3 else m
        above = abc[j - 1] if j > 0 else m
        quats[:, j] = np.where(which == j, m, np.where(j < which, below, above))

    col = words("packed_color")
    for k, (shift, name) in enumerate(((24, "r"), (16, "g"), (8, "b"))):
        t = ((col >> shift) & 255) / 255.0
        if f"min_{name}" in bound:
            t = bound[f"min_{name}"] * (1.0 - t) + bound[f"max_{name}"] * t
        sh_dc[:, k] = ((t - 0.5) / SH_C0).reshape(-1)[:n]
    opacity[:] = _LOGIT[col.reshape(-1)[:n] & 255]


def _spread(v: np.ndarray) -> np.ndarray:
    v = v & 0x3FF
    v = (v ^ (v << 16)) & 0xFF0000FF
    v = (v ^ (v << 8)) & 0x0300F00F
    v = (v ^ (v << 4)) & 0x030C30C3
    return (v ^ (v << 2)) & 0x09249249


def morton_order(means: np.ndarray) -> np.ndarray:
    """Return the ``[N]`` permutation that sorts centres ``[N, 3]`` along a Morton (Z-order) curve.

    The same order as splat-transform's ``sortMortonOrder``: 10 bits per axis over the bounding box, a stable sort,
    and every run of more than 256 equal codes sorted again over its own box. Chunks of 256 consecutive Gaussians then
    cover small boxes, which keeps the 11/10/11-bit positions and scales fine, and files written here carry their
    Gaussians in the order splat-transform would write them.
    """
    pts = means.astype(np.float64)
    order = np.arange(len(pts))

    def generate(idx: np.ndarray) -> np.ndarray:
        p = pts[idx]
        lo, hi = p.min(axis=0), p.max(axis=0)
        length = hi - lo
        if not np.all(np.isfinite(length)) or not np.any(length):
            return idx
        mul = np.where(length == 0, 0.0, 1024.0 / np.where(length == 0, 1.0, length))
        q = np.minimum(1023.0, (p - lo) * mul).astype(np.int64)
        code = _spread(q[:, 0]) + (_spread(q[:, 1]) << 1) + (_spread(q[:, 2]) << 2)
        perm = np.argsort(code, kind="stable")
        idx, code = idx[perm], code[perm]
        starts = np.flatnonzero(np.r_[True, code[1:] != code[:-1]])
        ends = np.r_[starts[1:], len(code)]
        for a, b in zip(starts, ends):
            if b - a > CHUNK:
                idx[a:b] = generate(idx[a:b])
        return idx

    return generate(order) if len(pts) else order


def _pack_unorm(v: np.ndarray, bits: int) -> np.ndarray:
    t = (1 << bits) - 1
    return np.clip(np.floor(v * t + 0.5), 0, t).astype(np.uint32)


def _normalise(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """splat-transform's normalize: 0 at or below min, 1 at or above max, 0 for a chunk of (nearly) one value."""
    span = hi - lo
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(span < 1e-5, 0.0, (x - lo) / np.where(span < 1e-5, 1.0, span))
    return np.where(x <= lo, 0.0, np.where(x >= hi, 1.0, t))


def encode_compressed_ply(cloud: GaussianCloud) -> bytes:
    """Return the bytes of ``cloud`` as a PlayCanvas compressed PLY (Morton-sorted; SH as ``uchar`` when present)."""
    n = len(cloud)
    order = morton_order(cloud.means.astype(np.float64))
    n_chunks = -(-n // CHUNK)
    pad = np.concatenate([order, np.full(n_chunks * CHUNK - n, order[-1])])  # repeat the last row as splat-transform

    def chunked(a: np.ndarray) -> np.ndarray:
        return a.astype(np.float64)[pad].reshape(n_chunks, CHUNK, *a.shape[1:])

    means = chunked(cloud.means)
    log_scales = chunked(cloud.log_scales)
    # splat-transform stores the colour in a Float32Array before taking bounds: round alike so files match its own
    rgb = (chunked(cloud.sh_dc) * SH_C0 + 0.5).astype(np.float32).astype(np.float64)
    pmin, pmax = means.min(axis=1, keepdims=True), means.max(axis=1, keepdims=True)
    smin = np.clip(log_scales.min(axis=1, keepdims=True), -_SCALE_LIMIT, _SCALE_LIMIT)
    smax = np.clip(log_scales.max(axis=1, keepdims=True), -_SCALE_LIMIT, _SCALE_LIMIT)
    cmin, cmax = rgb.min(axis=1, keepdims=True), rgb.max(axis=1, keepdims=True)

    def pack_111011(t: np.ndarray) -> np.ndarray:
        return (_pack_unorm(t[..., 0], 11) << 21) | (_pack_unorm(t[..., 1], 10) << 11) | _pack_unorm(t[..., 2], 11)

    packed_position = pack_111011(_normalise(means, pmin, pmax))
    packed_scale = pack_111011(_normalise(log_scales, smin, smax))
    c = _normalise(rgb, cmin, cmax)
    with np.errstate(over="ignore"):  # the plain formula, as splat-transform, so alpha bytes round alike
        alpha = 1.0 / (1.0 + np.exp(-chunked(cloud.opacity_logits)))
    packed_color = ((_pack_unorm(c[..., 0], 8) << 24) | (_pack_unorm(c[..., 1], 8) << 16)
                    | (_pack_unorm(c[..., 2], 8) << 8) | _pack_unorm(alpha, 8))

    q = chunked(cloud.quats_wxyz).reshape(-1, 4)
    qn = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(qn > 0, q / np.where(qn > 0, qn, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    largest = np.argmax(np.abs(q), axis=1)
    q = np.where(q[np.arange(len(q)), largest][:, None] < 0, -q, q)
    word = largest.astype(np.uint32)
    for i in range(4):
        v = _pack_unorm(q[:, i] * (np.sqrt(2.0) * 0.5) + 0.5, 10)
        word = np.where(largest != i, (word << 10) | v, word)
    packed_rotation = word.reshape(n_chunks, CHUNK)

    vertex = np.stack([packed_position, packed_rotation, packed_scale, packed_color], axis=-1).reshape(-1, 4)[:n]
    bounds = np.concatenate([pmin[:, 0], pmax[:, 0], smin[:, 0], smax[:, 0], cmin[:, 0], cmax[:, 0]], axis=1)
    lines = ["ply", "format binary_little_endian 1.0", "comment Generated by roodi-toolkit",
             f"element chunk {n_chunks}", *[f"property float {name}" for name in _CHUNK_BOUNDS + _CHUNK_COLOUR],
             f"element vertex {n}", *[f"property uint {name}" for name in _PACKED]]
    parts = [bounds.astype("<f4").tobytes(), vertex.astype("<u4").tobytes()]
    per = cloud.sh_rest.shape[1]
    if per:
        lines.append(f"element sh {n}")
        lines += [f"property uchar f_rest_{i}" for i in range(3 * per)]
        flat = cloud.sh_rest[order].astype(np.float64).transpose(0, 2, 1).reshape(n, 3 * per)  # channel-major
        parts.append(np.clip(np.trunc((flat / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8).tobytes())
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii") + b"".join(parts)


def write_compressed_ply(cloud: GaussianCloud, path: str | os.PathLike) -> Path:
    """Write ``cloud`` as a PlayCanvas compressed PLY, atomically; return the path."""
    data = encode_compressed_ply(cloud)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)
