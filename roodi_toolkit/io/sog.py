"""PlayCanvas SOG: a ``meta.json`` with lossless WebP textures beside it, or a ``.sog`` zip holding both.

Decoding follows splat-transform 2.7.1's ``readSog`` (version 2: scale/colour codebooks, opacity byte = sigmoid) and
``readSogV1`` (no ``version``: per-channel min/max, opacity stored as a logit range). Positions are 16-bit (two
8-bit textures) in ``sign(x) * log(|x| + 1)`` space; quaternions are three bytes plus a tag 252-255 naming the largest
component (w, x, y, z); higher SH come from a palette of centroids indexed by a 16-bit label. WebP is decoded with
Pillow. The data are in the 3DGS PLY frame already.
"""

from __future__ import annotations

import io
import os
import warnings
import zipfile
import zlib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import FormatError, InputError
from ..gaussians import GaussianCloud
from ..limits import check_memory
from .files import parse_json, pil_image

_MAX_COUNT = 1 << 28
_BYTES_PER_GAUSSIAN = 600  # peak memory of decoding one Gaussian (int64 texels, float64 steps, the cloud)


def _fail(p: Path | str, msg: str) -> FormatError:
    return FormatError(f"{p}: {msg}")


def _inv_log(v: np.ndarray) -> np.ndarray:
    return np.sign(v) * (np.exp(np.abs(v)) - 1.0)


def _sigmoid_inv(y: np.ndarray) -> np.ndarray:
    e = np.clip(y, 1e-6, 1 - 1e-6)
    return np.log(e / (1 - e))


_META_MAX_BYTES = 64 << 20  # meta.json: codebooks and ranges, kilobytes in practice
_CENTROID_MAX_PIXELS = 64 * 15 * 1024  # shN centroids: 64 palette entries of up to 15 coefficients a row, <= 1024 rows


def _texture_pixel_limit(count: int) -> int:
    """Most pixels a per-Gaussian texture of ``count`` Gaussians may have. splat-transform lays ``count`` pixels out
    ``ceil(sqrt(count) / 4) * 4`` wide and a multiple of 4 high (a few rows spare); four times the count plus 64 K
    leaves room for any sane layout, and refuses a header that claims a 16383x10923 texture for 1,000 Gaussians."""
    return 4 * count + (1 << 16)


def _byte_limit(pixels: int) -> int:
    """Most bytes a WebP file of ``pixels`` pixels may hold: lossless WebP of noise is about 4 bytes a pixel."""
    return 5 * pixels + (1 << 20)


def read_sog(path: str | os.PathLike) -> GaussianCloud:
    """Return the Gaussians of a ``.sog`` zip or of a SOG ``meta.json`` (textures beside it).

    Nothing larger than the count in ``meta.json`` justifies is read or decoded: a zip entry or texture file is read
    up to the bytes its pixels may take (so a zip entry that inflates to gigabytes stops there), and a WebP header's
    size is checked against the count before the pixels are decoded.

    Raises:
        FormatError: not a zip / JSON, missing meta.json or texture, a texture that is not WebP, too small or too
            large for the count, an unsupported SOG version, malformed metadata.
    """
    p = Path(path)
    if zipfile.is_zipfile(p):
        try:
            zf = zipfile.ZipFile(p)
        except (zipfile.BadZipFile, OSError) as exc:
            raise _fail(p, f"corrupt SOG zip ({exc})") from None
        names = set(zf.namelist())
        meta_name = "meta.json" if "meta.json" in names else next((n for n in names if n.endswith("meta.json")), None)
        if meta_name is None:
            raise _fail(p, "SOG zip holds no meta.json")
        base = meta_name[: -len("meta.json")]

        def load(name: str, limit: int) -> bytes:
            try:
                info = zf.getinfo(base + name)
            except KeyError:
                raise _fail(p, f"SOG zip lacks {base + name!r} named in meta.json") from None
            if info.file_size > limit:
                raise _fail(p, f"SOG zip entry {name!r} declares {info.file_size:,} bytes, more than the count in "
                               f"meta.json can need ({limit:,}): corrupt or a decompression bomb")
            try:
                with zf.open(info) as f:  # inflates no more than asked, whatever the entry's header says
                    data = f.read(limit + 1)
            except (zipfile.BadZipFile, OSError, EOFError, RuntimeError, ValueError, zlib.error) as exc:
                raise _fail(p, f"SOG zip entry {name!r} is corrupt ({exc})") from None
            if len(data) > limit:
                raise _fail(p, f"SOG zip entry {name!r} inflates to more than the count in meta.json can need "
                               f"({limit:,} bytes): corrupt or a decompression bomb")
            return data

        meta_bytes = load("meta.json", _META_MAX_BYTES)
    else:
        folder = p.parent

        def load(name: str, limit: int) -> bytes:
            f = folder / name
            if not f.is_file():
                raise _fail(p, f"SOG texture {name!r} named in meta.json is missing beside it")
            size = f.stat().st_size
            if size > limit:
                raise _fail(p, f"SOG file {name!r} holds {size:,} bytes, more than the count in meta.json can need "
                               f"({limit:,})")
            try:
                return f.read_bytes()
            except OSError as exc:
                raise _fail(p, f"cannot read SOG file {name!r} ({exc.strerror or exc})") from None

        if p.stat().st_size > _META_MAX_BYTES:
            raise _fail(p, f"SOG meta.json holds {p.stat().st_size:,} bytes, more than any meta.json needs")
        meta_bytes = p.read_bytes()
    try:
        meta = parse_json(meta_bytes, p, "SOG meta.json")
    except InputError as exc:
        raise FormatError(str(exc)) from None
    if not isinstance(meta, dict):
        raise _fail(p, "SOG meta.json is malformed (not a JSON object)")
    try:
        return _decode(p, meta, load)
    except (KeyError, TypeError, IndexError, ValueError, OverflowError) as exc:
        raise _fail(p, f"SOG meta.json is malformed ({type(exc).__name__}: {exc})") from None


def _webp_size(data: bytes) -> tuple[int, int] | None:
    """Return a WebP file's (width, height) from its header (the VP8X canvas, or the VP8L / VP8 frame), or None if
    it is no WebP. Read here, not by Pillow: opening a WebP, Pillow's decoder already allocates the whole canvas."""
    if len(data) < 30 or data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        return None
    kind = data[12:16]
    if kind == b"VP8X":
        return 1 + int.from_bytes(data[24:27], "little"), 1 + int.from_bytes(data[27:30], "little")
    if kind == b"VP8L" and data[20] == 0x2F:
        bits = int.from_bytes(data[21:25], "little")
        return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    if kind == b"VP8 " and data[23:26] == b"\x9d\x01\x2a":
        return int.from_bytes(data[26:28], "little") & 0x3FFF, int.from_bytes(data[28:30], "little") & 0x3FFF
    return None


def _open_webp(p: Path, name: str, data: bytes, max_pixels: int) -> Any:
    """Return Pillow's (not yet decoded) image of a WebP texture whose size is at most ``max_pixels``."""
    Image = pil_image()
    size = _webp_size(data)
    if size is not None and size[0] * size[1] > max_pixels:
        raise _fail(p, f"SOG texture {name!r} claims {size[0]}x{size[1]} pixels, more than the count in meta.json can "
                       f"need ({max_pixels:,}): corrupt or a decompression bomb")
    limit = Image.MAX_IMAGE_PIXELS
    try:
        Image.MAX_IMAGE_PIXELS = None  # the bound is ours, from the count (Pillow would warn on stderr)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(data))
    except Image.UnidentifiedImageError:
        raise _fail(p, f"SOG texture {name!r} is not a readable image") from None
    except (OSError, SyntaxError, ValueError) as exc:
        raise _fail(p, f"SOG texture {name!r} is not a readable WebP image ({' '.join(str(exc).split())[:160]})") \
            from None
    finally:
        Image.MAX_IMAGE_PIXELS = limit
    if im.format != "WEBP":
        im.close()
        raise _fail(p, f"SOG texture {name!r} is {im.format}, not WebP")
    w, h = im.size
    if w * h > max_pixels:
        im.close()
        raise _fail(p, f"SOG texture {name!r} claims {w}x{h} pixels, more than the count in meta.json can need "
                       f"({max_pixels:,}): corrupt or a decompression bomb")
    return im


def _texture(p: Path, load: Callable[[str, int], bytes], name: str, count: int,
             max_pixels: int | None = None) -> np.ndarray:
    """Return the first ``count`` RGBA pixels ``[count, 4]`` of a WebP texture, row-major.

    ``max_pixels``: the most pixels the texture may have (default from ``count``, :func:`_texture_pixel_limit`).
    """
    max_pixels = _texture_pixel_limit(count) if max_pixels is None else max_pixels
    data = load(name, _byte_limit(max_pixels))
    with _open_webp(p, name, data, max_pixels) as im:
        w, h = im.size
        if w * h < count:
            raise _fail(p, f"SOG texture {name!r} has {w * h} pixels, fewer than the {count} Gaussians")
        check_memory(16.0 * w * h, f"{p}: decoding its {w}x{h} texture {name!r}", "convert it on a larger machine",
                     FormatError)
        try:
            rgba = np.asarray(im.convert("RGBA"))
        except (OSError, SyntaxError, ValueError) as exc:
            raise _fail(p, f"SOG texture {name!r} is not a readable WebP image "
                           f"({' '.join(str(exc).split())[:160]})") from None
    flat = rgba.reshape(-1, 4)
    return flat[:count].astype(np.int64)


def _decode(p: Path, meta: dict, load: Callable[[str, int], bytes]) -> GaussianCloud:
    version = meta.get("version")
    if version not in (None, 2):
        raise _fail(p, f"SOG version {version} is not supported (1 or 2)")
    count = int(meta["count"]) if version == 2 else int(meta["means"]["shape"][0])
    if count <= 0 or count > _MAX_COUNT:
        raise _fail(p, f"SOG count {count} is out of range")
    check_memory(_BYTES_PER_GAUSSIAN * count, f"{p}: reading its {count:,} Gaussians", "convert it on a larger machine",
                 FormatError)
    lo = _texture(p, load, meta["means"]["files"][0], count)
    hi = _texture(p, load, meta["means"]["files"][1], count)
    q16 = (lo[:, :3] | (hi[:, :3] << 8)).astype(np.float64) / 65535.0
    mins, maxs = np.asarray(meta["means"]["mins"], float), np.asarray(meta["means"]["maxs"], float)
    span = np.where(maxs - mins == 0, 1.0, maxs - mins)
    means = _inv_log(mins + span * q16)

    qt = _texture(p, load, meta["quats"]["files"][0], count)
    tag = qt[:, 3]
    abc = (qt[:, :3] / 255.0 * 2.0 - 1.0) / np.sqrt(2.0)
    quats = np.zeros((count, 4))
    valid = (tag >= 252) & (tag <= 255)
    largest = np.clip(tag - 252, 0, 3)
    slots = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[largest]
    rows = np.arange(count)
    for k in range(3):
        quats[rows, slots[:, k]] = abc[:, k]
    quats[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - np.sum(abc * abc, axis=1)))
    quats[~valid] = [1.0, 0.0, 0.0, 0.0]  # splat-transform: an invalid tag is the identity

    st = _texture(p, load, meta["scales"]["files"][0], count)
    ct = _texture(p, load, meta["sh0"]["files"][0], count)
    if version == 2:
        scode = np.asarray(meta["scales"]["codebook"], dtype=np.float32)
        ccode = np.asarray(meta["sh0"]["codebook"], dtype=np.float32)
        if len(scode) != 256 or len(ccode) != 256:
            raise _fail(p, "SOG codebooks must have 256 entries")
        log_scales = scode[st[:, :3]].astype(np.float64)
        sh_dc = ccode[ct[:, :3]].astype(np.float64)
        opacity = _sigmoid_inv(ct[:, 3] / 255.0)
    else:
        smin, smax = np.asarray(meta["scales"]["mins"], float), np.asarray(meta["scales"]["maxs"], float)
        log_scales = smin + (smax - smin) * (st[:, :3] / 255.0)
        cmin, cmax = np.asarray(meta["sh0"]["mins"], float), np.asarray(meta["sh0"]["maxs"], float)
        sh_dc = cmin[:3] + (cmax[:3] - cmin[:3]) * (ct[:, :3] / 255.0)
        opacity = cmin[3] + (cmax[3] - cmin[3]) * (ct[:, 3] / 255.0)

    rest = np.zeros((count, 0, 3), dtype=np.float32)
    sh_meta = meta.get("shN")
    if sh_meta:
        centroids_name, labels_name = sh_meta["files"][0], sh_meta["files"][1]
        cdata = load(centroids_name, _byte_limit(_CENTROID_MAX_PIXELS))
        with _open_webp(p, centroids_name, cdata, _CENTROID_MAX_PIXELS) as im:
            cw, chh = im.size
        cen = _texture(p, load, centroids_name, cw * chh, _CENTROID_MAX_PIXELS).reshape(chh, cw, 4)
        if version == 2:
            coeffs = [0, 3, 8, 15][int(sh_meta["bands"])]
            if cw != 64 * coeffs:
                raise _fail(p, f"SOG shN centroids width {cw} does not match {sh_meta['bands']} bands")
            code = np.asarray(sh_meta["codebook"], dtype=np.float32)
            dequant = lambda b: code[b].astype(np.float64)  # noqa: E731
        else:
            coeffs = {192: 3, 512: 8, 960: 15}.get(cw, 0)
            if not coeffs:
                raise _fail(p, f"SOG shN centroids width {cw} is none of 192, 512, 960")
            smn, smx = float(sh_meta["mins"]), float(sh_meta["maxs"])
            dequant = lambda b: smn + (smx - smn) * (b / 255.0)  # noqa: E731
        lab = _texture(p, load, labels_name, count)
        label = lab[:, 0] | (lab[:, 1] << 8)
        palette = (cw // coeffs) * chh
        ok = label < palette
        label = np.where(ok, label, 0)
        cx = (label[:, None] % 64) * coeffs + np.arange(coeffs)[None, :]  # [N, coeffs]
        cy = np.broadcast_to((label // 64)[:, None], cx.shape)
        inside = (cx < cw) & (cy < chh) & ok[:, None]
        px = cen[np.minimum(cy, chh - 1), np.minimum(cx, cw - 1), :3]  # [N, coeffs, 3]
        vals = np.where(inside[..., None], dequant(px), 0.0)
        rest = vals.astype(np.float32)  # [N, coeffs, 3]: coefficient-major, channel last
    return GaussianCloud(means=means.astype(np.float32), quats_wxyz=quats.astype(np.float32),
                         log_scales=log_scales.astype(np.float32), opacity_logits=opacity.astype(np.float32),
                         sh_dc=sh_dc.astype(np.float32), sh_rest=np.ascontiguousarray(rest))
