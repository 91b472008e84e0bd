"""Niantic SPZ (``.spz``): versions 1-3 (one gzip stream) and 4 (32-byte header, TOC, zstd streams).

Facts from the format's reference implementation (github nianticlabs/spz, ``load-spz.cc``): positions are 24-bit
signed fixed point with ``fractionalBits`` from the header; scales ``s / 16 - 10`` (log); alpha ``logit(a / 255)``;
colour is the SH DC coefficient ``(c / 255 - 0.5) / 0.15``; rotations are xyzw, "smallest three" (2-bit index + 3 x
(sign + 9 bits), scaled by 1/sqrt(2)) from version 3 and "first three" (xyz bytes, w >= 0) before; SH coefficients
``(v - 128) / 128``, coefficient-major with the colour channel fastest. Data are stored in the RUB frame (x right, y
up, z back) and 3DGS PLY is RDF (y down, z forward): y and z flip, quaternion x,y,z flip by (1, -1, -1) and each SH
coefficient by the sign of its basis function under that flip. Skipping this flip is what misplaces an SPZ in other
tools (gsply 0.4.6's SPZ lands off by the scene's size in splat-transform).

We write version 3 (gzip), which every SPZ reader accepts (Scaniverse, splat-transform, web viewers), with the
reference packer's quantisation, including its SH buckets (5 bits for degree 1, 4 above).
"""

from __future__ import annotations

import gzip
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..gaussians import GaussianCloud, sigmoid
from ..limits import check_memory
from .files import atomic_path

MAGIC = 0x5053474E  # "NGSP" little-endian
COLOR_SCALE = 0.15
_SQRT1_2 = np.float32(0.7071067811865476)
# sign of each SH coefficient (degrees 1-3, 15 per channel) under the RUB <-> RDF flip (x = 1, y = z = -1)
_FLIP_SH = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], dtype=np.float32)
_FLIP_Q = np.array([1.0, -1.0, -1.0], dtype=np.float32)  # x, y, z of an xyzw quaternion
_MAX_POINTS = 1 << 28  # refuse absurd counts before allocating (the reference has none; 268M Gaussians is ~20 GB)
_BYTES_PER_GAUSSIAN = 400  # peak memory of decoding one Gaussian of SH degree 3 (bytes, int32/float32 steps, cloud)


def _fail(p: Path | str, msg: str) -> FormatError:
    return FormatError(f"{p}: {msg}")


_HEADER_BYTES = 16
_DEFLATE_MAX_RATIO = 1100  # deflate's best is 1032:1: fewer compressed bytes than need / this cannot hold the data


def _check_memory(p: Path, n: int) -> None:
    check_memory(_BYTES_PER_GAUSSIAN * n, f"{p}: reading its {n:,} Gaussians", "convert it on a larger machine",
                 FormatError)


class _GzipStream:
    """Inflate an SPZ's gzip stream (concatenated members too) only as far as asked: the header first, then exactly
    the bytes the header's count needs, so a stream that inflates to gigabytes past them is never inflated."""

    def __init__(self, p: Path, raw: bytes) -> None:
        self.p, self.rest = p, raw
        self.inflater = zlib.decompressobj(wbits=31)

    def read(self, size: int) -> bytes:
        """Return the next ``size`` inflated bytes (fewer where the stream ends first)."""
        parts, got = [], 0
        try:
            while got < size:
                chunk = self.inflater.decompress(self.rest, size - got)
                self.rest = self.inflater.unconsumed_tail
                parts.append(chunk)
                got += len(chunk)
                if self.inflater.eof:  # a member ended: another may follow (gzip allows several)
                    tail = self.inflater.unused_data
                    if not tail:
                        break
                    self.inflater, self.rest = zlib.decompressobj(wbits=31), tail
                elif not chunk and not self.rest:
                    break
        except zlib.error as exc:
            raise _fail(self.p, f"SPZ gzip stream is corrupt or truncated ({exc})") from None
        return b"".join(parts)


def _streams_v4(p: Path, raw: bytes, num_streams: int, toc: int, expected: list[int]) -> list[bytes]:
    try:
        import zstandard  # lazy: every import of the package reads splat files; only SPZ version 4 needs it
    except ImportError:  # pragma: no cover - a dependency of the package
        raise _fail(p, "SPZ version 4 needs the zstandard package: pip install zstandard") from None
    if toc < 32 or toc + 16 * num_streams > len(raw):
        raise _fail(p, "SPZ table of contents lies outside the file: truncated or corrupt")
    entries = np.frombuffer(raw, dtype="<u8", count=2 * num_streams, offset=toc).reshape(-1, 2)
    offset = toc + 16 * num_streams
    out = []
    dctx = zstandard.ZstdDecompressor()
    for k, (csize, usize) in enumerate(entries.tolist()):
        if k < len(expected) and usize != expected[k]:  # checked before decompressing: no allocation from a bad TOC
            raise _fail(p, f"SPZ stream {k} declares {usize} bytes, the header's count needs {expected[k]}: corrupt")
        if k >= len(expected) and usize > 0:
            raise _fail(p, f"SPZ holds an unexpected stream {k}: corrupt or a newer version")
        if offset + csize > len(raw):
            raise _fail(p, f"SPZ stream {k} ends past the end of the file: truncated")
        chunk = raw[offset:offset + csize]
        try:
            # a frame that declares its size is decompressed into that much memory, whatever max_output_size says:
            # a corrupt size (2^60) must be refused before zstd allocates it
            declared = zstandard.frame_content_size(chunk)
            if declared not in (-1, usize):
                raise _fail(p, f"SPZ stream {k} declares {declared} bytes, its TOC says {usize}: corrupt")
            data = dctx.decompress(chunk, max_output_size=usize)
        except zstandard.ZstdError as exc:
            raise _fail(p, f"SPZ stream {k} is corrupt ({exc})") from None
        if len(data) != usize:
            raise _fail(p, f"SPZ stream {k} holds {len(data)} bytes, its TOC says {usize}: corrupt")
        out.append(data)
        offset += csize
    return out


def _open_spz(p: Path, raw: bytes) -> tuple[int, int, int, int, _GzipStream | None, list[bytes] | None]:
    """Return the header's version, Gaussian count, SH degree and fractional bits, and where the data are: the gzip
    stream past the header (versions 1-3) or the decompressed streams (version 4; empty when the header's count or
    degree is out of range, which the caller refuses).

    Raises:
        FormatError: no SPZ magic, an unsupported version, a truncated header, corrupt version 4 streams.
    """
    if raw[:2] == b"\x1f\x8b":
        gz = _GzipStream(p, raw)
        head = gz.read(_HEADER_BYTES)
        if len(head) < _HEADER_BYTES:
            raise _fail(p, "SPZ header is truncated")
        magic, version, n, degree, frac, flags, _ = struct.unpack_from("<IIIBBBB", head)
        if magic != MAGIC:
            raise _fail(p, "gzip data is not an SPZ file (no NGSP magic)")
        if version not in (1, 2, 3):
            raise _fail(p, f"gzip SPZ version {version} is not supported (1-3)")
        return version, n, degree, frac, gz, None
    if len(raw) >= 32 and raw[:4] == b"NGSP":
        magic, version, n, degree, frac, flags, num_streams, toc = struct.unpack_from("<IIIBBBBI", raw)
        if version != 4:
            raise _fail(p, f"SPZ version {version} with a plain header is not supported (expected 4)")
        streams: list[bytes] = []
        if degree <= 3 and 0 < n <= _MAX_POINTS:
            _check_memory(p, n)
            dim4 = (degree + 1) ** 2 - 1
            expected = [9 * n, n, 3 * n, 3 * n, 4 * n] + ([3 * dim4 * n] if dim4 else [])
            streams = _streams_v4(p, raw, num_streams, toc, expected)
        return version, n, degree, frac, None, streams
    raise _fail(p, "not an SPZ file (neither gzip nor NGSP magic)")


def _gzip_sections(p: Path, raw: bytes, gz: _GzipStream, n: int, sizes: list[int]) -> list[np.ndarray]:
    """Return the byte arrays of the sections (positions, alphas, colours, scales, rotations, SH) inflated from a
    version 1-3 stream, no further than their ``sizes`` need.

    Raises:
        FormatError: too few compressed bytes for the count, or a stream that ends early.
    """
    need = sum(sizes)
    if len(raw) * _DEFLATE_MAX_RATIO < need:
        raise _fail(p, f"SPZ file holds {len(raw):,} compressed bytes, too few for the {need:,} that {n:,} "
                       "Gaussians need: truncated or a corrupt count")
    _check_memory(p, n)
    body = gz.read(need)  # no further: whatever follows the count's data is never inflated
    if len(body) < need:
        raise _fail(p, f"SPZ data holds {len(body)} bytes, {n} Gaussians need {need}: truncated")
    parts, off = [], 0
    for s in sizes:
        parts.append(np.frombuffer(body, dtype=np.uint8, count=s, offset=off))
        off += s
    return parts


def _v4_sections(p: Path, streams: list[bytes], n: int, degree: int, sizes: list[int]) -> list[np.ndarray]:
    """Return the byte arrays of the sections from a version 4 file's streams, one stream each.

    Raises:
        FormatError: too few streams for the SH degree, or a stream whose size does not match the count.
    """
    dim = (degree + 1) ** 2 - 1
    if len(streams) < 5 or (dim and len(streams) < 6):
        raise _fail(p, f"SPZ holds {len(streams)} streams, SH degree {degree} needs {6 if dim else 5}")
    parts = []
    for k, s in enumerate(sizes):
        data = streams[k] if k < len(streams) else b""
        if len(data) != s:
            raise _fail(p, f"SPZ stream {k} holds {len(data)} bytes, {n} Gaussians need {s}: corrupt")
        parts.append(np.frombuffer(data, dtype=np.uint8))
    return parts


def _decode_means(pos_b: np.ndarray, n: int, version: int, frac: int) -> np.ndarray:
    """Return the positions ``[n, 3]`` in the PLY frame: half floats (version 1) or 24-bit fixed point with ``frac``
    fractional bits."""
    if version == 1:
        means = np.frombuffer(pos_b.tobytes(), dtype="<f2").astype(np.float32).reshape(n, 3)
    else:
        b = pos_b.reshape(n * 3, 3).astype(np.int32)
        fixed = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)
        fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
        means = (fixed.astype(np.float32) * np.float32(1.0 / (1 << frac))).reshape(n, 3)
    return means * np.array([1.0, -1.0, -1.0], dtype=np.float32)


def _decode_rotations(rot_b: np.ndarray, n: int, version: int) -> np.ndarray:
    """Return the quaternions ``[n, 4]`` wxyz in the PLY frame: "smallest three" (version 3 on) or "first three"."""
    if version >= 3:
        comp = rot_b.reshape(n, 4).astype(np.uint32)
        comp = comp[:, 0] | (comp[:, 1] << 8) | (comp[:, 2] << 16) | (comp[:, 3] << 24)
        largest = (comp >> 30).astype(np.int64)
        xyzw = np.zeros((n, 4), dtype=np.float32)
        rows = np.arange(n)
        for i in range(3, -1, -1):  # the reference unpacks from the last component down, skipping the largest
            skip = largest == i
            mag = (comp & 511).astype(np.float32)
            neg = (comp >> 9) & 1
            val = _SQRT1_2 * mag / np.float32(511.0)
            val = np.where(neg == 1, -val, val)
            xyzw[:, i] = np.where(skip, 0.0, val)
            comp = np.where(skip, comp, comp >> 10)
        xyzw[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - np.sum(xyzw * xyzw, axis=1)))
    else:
        xyz = rot_b.reshape(n, 3).astype(np.float32) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - np.sum(xyz * xyz, axis=1)))
        xyzw = np.concatenate([xyz, w[:, None]], axis=1)
    xyzw[:, :3] *= _FLIP_Q
    return xyzw[:, [3, 0, 1, 2]]


def _decode_sh_rest(sh_b: np.ndarray, n: int, dim: int) -> np.ndarray:
    """Return the SH coefficients above degree 0 ``[n, dim, 3]`` in the PLY frame."""
    if not dim:
        return np.zeros((n, 0, 3), dtype=np.float32)
    rest = (sh_b.reshape(n, dim, 3).astype(np.float32) - 128.0) / 128.0
    rest *= _FLIP_SH[:dim, None]
    return rest


def read_spz(path: str | os.PathLike) -> GaussianCloud:
    """Return the Gaussians of an SPZ file (versions 1-4), converted to the 3DGS PLY frame (RDF).

    Alpha bytes 0 and 255 decode to logits -inf and +inf (as the reference does); the caller makes them finite.

    Raises:
        FormatError: bad magic, unsupported version or SH degree, sizes that do not match the count, truncated or
            corrupt compressed data.
    """
    p = Path(path)
    raw = p.read_bytes()
    version, n, degree, frac, gz, streams = _open_spz(p, raw)
    if degree > 3:
        raise _fail(p, f"SPZ SH degree {degree} is not supported (0-3)")
    if n == 0:
        raise _fail(p, "SPZ file declares 0 Gaussians: there are none to read")
    if n > _MAX_POINTS:
        raise _fail(p, f"SPZ file declares {n} Gaussians, more than this reader accepts ({_MAX_POINTS})")
    dim = (degree + 1) ** 2 - 1
    pos_bytes = 6 if version == 1 else 9
    rot_bytes = 4 if version >= 3 else 3
    sizes = [n * pos_bytes, n, 3 * n, 3 * n, n * rot_bytes, n * dim * 3]
    if streams is None:
        parts = _gzip_sections(p, raw, gz, n, sizes)
    else:
        parts = _v4_sections(p, streams, n, degree, sizes)
    pos_b, alpha_b, colour_b, scale_b, rot_b, sh_b = parts

    means = _decode_means(pos_b, n, version, frac)
    log_scales = scale_b.reshape(n, 3).astype(np.float32) / 16.0 - 10.0
    with np.errstate(divide="ignore"):
        a = alpha_b.astype(np.float32) / 255.0
        opacity = np.log(a) - np.log1p(-a)
    sh_dc = (colour_b.reshape(n, 3).astype(np.float32) / 255.0 - 0.5) / COLOR_SCALE
    quats = _decode_rotations(rot_b, n, version)
    rest = _decode_sh_rest(sh_b, n, dim)
    return GaussianCloud(means=means.astype(np.float32), quats_wxyz=np.ascontiguousarray(quats, dtype=np.float32),
                         log_scales=log_scales, opacity_logits=opacity.astype(np.float32), sh_dc=sh_dc,
                         sh_rest=np.ascontiguousarray(rest))


def _to_u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def encode_spz(cloud: GaussianCloud) -> bytes:
    """Return ``cloud`` as SPZ version 3 bytes (gzip); see :func:`_encode_spz` (values beyond the bytes' range, such
    as a colour of -1e38 or a quaternion of 1e30, are clipped without numpy's overflow warnings)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _encode_spz(cloud)


def _encode_spz(cloud: GaussianCloud) -> bytes:
    """Return ``cloud`` as SPZ version 3 bytes (gzip), in the RUB frame SPZ readers expect.

    The fixed-point precision is the reference's 12 fractional bits unless the scene is larger than 24-bit fixed
    point can hold at that precision (|x| >= 2048): then as many bits as fit.

    Raises:
        FormatError: SH degree above 3 cannot occur; positions too far out for 24 bits even with 0 fractional bits.
    """
    n = len(cloud)
    degree = cloud.sh_degree
    dim = (degree + 1) ** 2 - 1
    means = cloud.means.astype(np.float64) * np.array([1.0, -1.0, -1.0])
    extent = float(np.max(np.abs(means))) if n else 0.0
    frac = 12
    while frac > 0 and extent * (1 << frac) >= (1 << 23) - 1:
        frac -= 1
    if extent * (1 << frac) >= (1 << 23) - 1:
        raise FormatError(f"positions reach {extent:.4g}, beyond what SPZ's 24-bit fixed point can hold")
    fixed = np.round(means * (1 << frac)).astype(np.int64).reshape(-1)
    pos = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, (fixed >> 16) & 0xFF], axis=1).astype(np.uint8)
    alpha = _to_u8(sigmoid(cloud.opacity_logits.astype(np.float32)) * 255.0)
    colour = _to_u8(cloud.sh_dc.astype(np.float32) * (COLOR_SCALE * 255.0) + 0.5 * 255.0)
    scales = _to_u8((cloud.log_scales.astype(np.float32) + 10.0) * 16.0)

    q = cloud.quats_wxyz.astype(np.float32)[:, [1, 2, 3, 0]]  # xyzw
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32))
    q[:, :3] *= _FLIP_Q
    largest = np.argmax(np.abs(q), axis=1)
    negate = q[np.arange(n), largest] < 0
    comp = largest.astype(np.uint32)
    for i in range(4):
        negbit = ((q[:, i] < 0) ^ negate).astype(np.uint32)
        mag = (np.float32(511.0) * (np.abs(q[:, i]) / _SQRT1_2) + np.float32(0.5)).astype(np.uint32)
        comp = np.where(largest != i, (comp << 10) | (negbit << 9) | mag, comp)
    rot = np.stack([(comp >> s) & 0xFF for s in (0, 8, 16, 24)], axis=1).astype(np.uint8)

    parts = [pos, alpha, colour, scales, rot]
    if dim:
        sh = cloud.sh_rest.astype(np.float32) * _FLIP_SH[:dim, None]
        bucket = np.where(np.arange(dim) < 3, 1 << (8 - 5), 1 << (8 - 4))[None, :, None]
        qv = np.round(sh * 128.0).astype(np.int32) + 128
        qv = (qv + bucket // 2) // bucket * bucket
        parts.append(np.clip(qv, 0, 255).astype(np.uint8))
    header = struct.pack("<IIIBBBB", MAGIC, 3, n, degree, frac, 0, 0)
    # mtime=0: the same splat gives the same bytes (reproducible outputs, diffable caches)
    return gzip.compress(header + b"".join(a.tobytes() for a in parts), compresslevel=6, mtime=0)


def write_spz(cloud: GaussianCloud, path: str | os.PathLike) -> Path:
    """Write ``cloud`` as SPZ version 3, atomically; return the path."""
    try:
        data = encode_spz(cloud)
    except FormatError as exc:  # what cannot be encoded, said of the file being written
        message = str(exc)
        raise FormatError(message if message.startswith(str(path)) else f"{path}: {message}") from None
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)
