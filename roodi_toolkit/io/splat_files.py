"""antimatter15 ``.splat`` and GaussianSplats3D ``.ksplat`` (read only).

``.splat``: 32 bytes per Gaussian, no header: position 3 x float32, linear scale 3 x float32, RGBA bytes (alpha =
opacity), rotation 4 bytes (w, x, y, z) mapped from [0, 255] to [-1, 1]. No SH.

``.ksplat``: a 4096-byte main header (version 0.1+, section count at byte 4, Gaussian count at 16, compression mode
0-2 at 20, SH range at 36/40), one 1024-byte header per section, then per section the partial-bucket sizes, bucket
centres and the Gaussians: mode 0 float32 everything; modes 1-2 uint16 positions relative to their bucket centre,
float16 scales and quaternions (w, x, y, z), RGBA bytes, SH as float16 (mode 1) or bytes over the SH range (mode 2),
stored per band and per channel. Decoding follows splat-transform 2.7.1's readers.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..gaussians import SH_C0, GaussianCloud

SPLAT_RECORD = 32
KSPLAT_MAIN_HEADER = 4096
KSPLAT_SECTION_HEADER = 1024
_EPS = 1e-6  # splat-transform clamps 8-bit opacities to [1e-6, 1 - 1e-6] before the logit


def _fail(p: Path | str, msg: str) -> FormatError:
    return FormatError(f"{p}: {msg}")


def _opacity_from_byte(a: np.ndarray) -> np.ndarray:
    o = np.clip(a.astype(np.float64) / 255.0, _EPS, 1.0 - _EPS)
    return np.log(o / (1.0 - o))


def _dc_from_byte(c: np.ndarray) -> np.ndarray:
    return (c.astype(np.float64) / 255.0 - 0.5) / SH_C0


def read_splat(path: str | os.PathLike) -> GaussianCloud:
    """Return the Gaussians of an antimatter15 ``.splat`` file.

    Raises:
        FormatError: empty file or a size that is not a multiple of 32 bytes (truncated or not a .splat).
    """
    p = Path(path)
    raw = p.read_bytes()
    if len(raw) == 0 or len(raw) % SPLAT_RECORD:
        raise _fail(p, f"a .splat file holds 32-byte records, this one has {len(raw)} bytes: truncated or not .splat")
    rec = np.frombuffer(raw, dtype=np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4),
                                             ("rot", "u1", 4)]))
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.log(rec["scale"].astype(np.float64))
    q = rec["rot"].astype(np.float64) / 255.0 * 2.0 - 1.0
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    quats = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    n = len(rec)
    return GaussianCloud(means=rec["pos"].astype(np.float32), quats_wxyz=quats.astype(np.float32),
                         log_scales=log_scales.astype(np.float32),
                         opacity_logits=_opacity_from_byte(rec["rgba"][:, 3]).astype(np.float32),
                         sh_dc=_dc_from_byte(rec["rgba"][:, :3]).astype(np.float32),
                         sh_rest=np.zeros((n, 0, 3), dtype=np.float32))


def looks_like_ksplat(head: bytes, size: int) -> bool:
    """Return whether the first bytes of a file are a plausible ``.ksplat`` main header."""
    if size < KSPLAT_MAIN_HEADER or len(head) < 44 or head[0] != 0 or head[1] < 1:
        return False
    sections = int.from_bytes(head[4:8], "little")
    mode = int.from_bytes(head[20:22], "little")
    count = int.from_bytes(head[16:20], "little")
    return 0 < sections < 1 << 16 and mode <= 2 and count > 0 and \
        KSPLAT_MAIN_HEADER + sections * KSPLAT_SECTION_HEADER <= size


# per compression mode: bytes of centre, scale, rotation, colour, one SH value; default quantisation range
_MODES = {0: (12, 12, 16, 4, 4, 1), 1: (6, 6, 8, 4, 2, 32767), 2: (6, 6, 8, 4, 1, 32767)}
_SH_COUNT = [0, 9, 24, 45]


def _sh_columns(count: int) -> np.ndarray:
    """Map ksplat's per-band, per-channel SH order to our ``[coeff, channel]`` flat index (coeff * 3 + channel)."""
    out = np.empty(count, dtype=np.int64)
    for i in range(count):
        if i < 9:
            channel, coeff = i // 3, i % 3
        elif i < 24:
            channel, coeff = (i - 9) // 5, (i - 9) % 5 + 3
        else:
            channel, coeff = (i - 24) // 7, (i - 24) % 7 + 8
        out[i] = coeff * 3 + channel
    return out


def _main_header(p: Path, raw: bytes) -> tuple[int, int, int, float, float]:
    """Return the main header's section count, Gaussian count, compression mode and SH range (mode 2's bytes).

    Raises:
        FormatError: a short file, an unsupported version or compression mode, a count of 0.
    """
    if len(raw) < KSPLAT_MAIN_HEADER:
        raise _fail(p, f"a .ksplat file starts with a {KSPLAT_MAIN_HEADER}-byte header, this one has {len(raw)} bytes")
    major, minor = raw[0], raw[1]
    if major != 0 or minor < 1:
        raise _fail(p, f"ksplat version {major}.{minor} is not supported (0.1 or later)")
    sections = int.from_bytes(raw[4:8], "little")
    total = int.from_bytes(raw[16:20], "little")
    mode = int.from_bytes(raw[20:22], "little")
    if mode not in _MODES:
        raise _fail(p, f"ksplat compression mode {mode} is not supported (0, 1 or 2)")
    if total == 0:
        raise _fail(p, "ksplat file declares 0 Gaussians: there are none to read")
    sh_lo = float(np.frombuffer(raw, "<f4", 1, 36)[0]) or -1.5
    sh_hi = float(np.frombuffer(raw, "<f4", 1, 40)[0]) or 1.5
    return sections, total, mode, sh_lo, sh_hi


def _bucket_indices(n: int, capacity: int, full: int, partial_sizes: np.ndarray) -> np.ndarray:
    """Return each of a section's ``n`` Gaussians' bucket ``[n]``: ``full`` buckets of ``capacity``, then the
    partial buckets of the given sizes."""
    idx = np.arange(n)
    bucket = np.where(idx < full * capacity, idx // max(capacity, 1), 0)
    if len(partial_sizes) and n > full * capacity:
        bounds = full * capacity + np.cumsum(partial_sizes)
        bucket = np.where(idx < full * capacity, bucket, full + np.searchsorted(bounds, idx, side="right"))
    return bucket


def _decode_records(rec: np.ndarray, mode: int, centres: np.ndarray, bucket: np.ndarray, block: float,
                    qrange: int, n_sh: int, degree: int, sh_range: tuple[float, float]) -> tuple[np.ndarray, ...]:
    """Return a section's Gaussians from its records ``[n, bytes]``: positions ``[n, 3]``, log scales ``[n, 3]``,
    quaternions ``[n, 4]`` wxyz, RGBA bytes ``[n, 4]`` and SH ``[n, coeff * 3 + channel]`` (zero-padded to the file's
    degree)."""
    cb, sb, rb = _MODES[mode][:3]
    hb = _MODES[mode][4]
    n = len(rec)
    if mode == 0:
        pos = rec[:, 0:12].copy().view("<f4").astype(np.float64)
        sc = rec[:, 12:24].copy().view("<f4").astype(np.float64)
        rot = rec[:, 24:40].copy().view("<f4").astype(np.float64)
    else:
        scale = block / 2.0 / qrange
        pos = (rec[:, 0:6].copy().view("<u2").astype(np.float64) - qrange) * scale + centres[bucket]
        sc = rec[:, 6:12].copy().view("<f2").astype(np.float64)
        rot = rec[:, 12:20].copy().view("<f2").astype(np.float64)
    c0 = cb + sb + rb
    rgba = rec[:, c0:c0 + 4]
    rest = np.zeros((n, _SH_COUNT[degree]), dtype=np.float64)  # [N, coeff * 3 + channel]
    if n_sh:
        raw_sh = rec[:, c0 + 4:c0 + 4 + n_sh * hb].copy()
        if mode == 0:
            vals = raw_sh.view("<f4").astype(np.float64)
        elif mode == 1:
            vals = raw_sh.view("<f2").astype(np.float64)
        else:
            sh_lo, sh_hi = sh_range
            vals = sh_lo + raw_sh.astype(np.float64) / 255.0 * (sh_hi - sh_lo)
        rest[:, _sh_columns(n_sh)] = vals
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.where(sc > 0, np.log(np.where(sc > 0, sc, 1.0)), -10.0)  # splat-transform: -10 if <= 0
    return pos, log_scales, rot, rgba, rest


def _read_section(p: Path, raw: bytes, h: np.ndarray, offset: int, mode: int, degree: int,
                  sh_range: tuple[float, float]) -> tuple[tuple[np.ndarray, ...] | None, int]:
    """Return the Gaussians of the section whose header is ``h`` and whose data start at ``offset`` (None for an
    empty section, else as :func:`_decode_records`), and the offset of the next section's data.

    Raises:
        FormatError: an SH degree above 3, data past the end of the file, bucket indices past the bucket count.
    """
    cb, sb, rb, colb, hb, default_range = _MODES[mode]
    u32 = h[:40].view("<u4")
    n, max_n, capacity, buckets = (int(v) for v in u32[:4])
    block = float(h[16:20].view("<f4")[0])
    bucket_bytes = int(h[20:22].view("<u2")[0])
    qrange = int(u32[6]) or default_range
    full, partial = int(u32[8]), int(u32[9])
    sec_degree = int(h[40:42].view("<u2")[0])
    if sec_degree > 3:
        raise _fail(p, f"ksplat SH degree {sec_degree} is not supported (0-3)")
    n_sh = _SH_COUNT[sec_degree]
    per = cb + sb + rb + colb + n_sh * hb
    meta_bytes = bucket_bytes * buckets + partial * 4
    size = per * max_n
    if n > max_n or offset + meta_bytes + size > len(raw):
        raise _fail(p, "ksplat section data run past the end of the file: truncated or corrupt")
    if n == 0:
        return None, offset + size + meta_bytes
    partial_sizes = np.frombuffer(raw, "<u4", partial, offset).astype(np.int64)
    centres = np.frombuffer(raw, "<f4", buckets * 3, offset + partial * 4).reshape(-1, 3).astype(np.float64)
    rec = np.frombuffer(raw, np.uint8, per * n, offset + meta_bytes).reshape(n, per)
    bucket = _bucket_indices(n, capacity, full, partial_sizes)
    if mode != 0 and (bucket.max() >= buckets):
        raise _fail(p, "ksplat bucket indices exceed the bucket count: corrupt")
    return _decode_records(rec, mode, centres, bucket, block, qrange, n_sh, degree, sh_range), \
        offset + size + meta_bytes


def read_ksplat(path: str | os.PathLike) -> GaussianCloud:
    """Return the Gaussians of a GaussianSplats3D ``.ksplat`` file.

    Raises:
        FormatError: unsupported version or compression mode, sections that run past the end of the file, a
            Gaussian count that disagrees with the sections.
    """
    p = Path(path)
    raw = p.read_bytes()
    sections, total, mode, sh_lo, sh_hi = _main_header(p, raw)
    data_offset = KSPLAT_MAIN_HEADER + sections * KSPLAT_SECTION_HEADER
    if data_offset > len(raw):
        raise _fail(p, f"ksplat declares {sections} sections whose headers run past the end of the file: truncated")
    heads = [np.frombuffer(raw, np.uint8, KSPLAT_SECTION_HEADER, KSPLAT_MAIN_HEADER + s * KSPLAT_SECTION_HEADER)
             for s in range(sections)]
    degree = max((int(h[40:42].view("<u2")[0]) for h in heads if h[0:4].view("<u4")[0]), default=0)
    if degree > 3:
        raise _fail(p, f"ksplat SH degree {degree} is not supported (0-3)")
    parts = []
    for h in heads:
        part, data_offset = _read_section(p, raw, h, data_offset, mode, degree, (sh_lo, sh_hi))
        if part is not None:
            parts.append(part)
    got = sum(len(x[0]) for x in parts)
    if got != total:
        raise _fail(p, f"ksplat header declares {total} Gaussians but its sections hold {got}: corrupt")
    pos, log_scales, rot, rgba, rest = (np.concatenate([x[k] for x in parts]) for k in range(5))
    dim = _SH_COUNT[degree] // 3
    return GaussianCloud(means=pos.astype(np.float32), quats_wxyz=rot.astype(np.float32),
                         log_scales=log_scales.astype(np.float32),
                         opacity_logits=_opacity_from_byte(rgba[:, 3]).astype(np.float32),
                         sh_dc=_dc_from_byte(rgba[:, :3]).astype(np.float32),
                         sh_rest=rest.reshape(total, dim, 3).astype(np.float32))
