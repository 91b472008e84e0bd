"""PlayCanvas SOG: a ``meta.json`` with lossless WebP textures beside it, or a ``.sog`` zip holding both.

Decoding follows splat-transform 2.7.1's ``readSog`` (version 2: scale/colour codebooks, opacity byte = sigmoid) and
``readSogV1`` (no ``version``: per-channel min/max, opacity stored as a logit range). Positions are 16-bit (two
8-bit textures) in ``sign(x) * log(|x| + 1)`` space; quaternions are three bytes plus a tag 252-255 naming the largest
component (w, x, y, z); higher SH come from a palette of centroids indexed by a 16-bit label. WebP is decoded with
Pillow. The data are in the 3DGS PLY frame already.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import FormatError
from ..gaussians import GaussianCloud

_MAX_COUNT = 1 << 28


def _fail(p: Path | str, msg: str) -> FormatError:
    return FormatError(f"{p}: {msg}")


def _inv_log(v: np.ndarray) -> np.ndarray:
    return np.sign(v) * (np.exp(np.abs(v)) - 1.0)


def _sigmoid_inv(y: np.ndarray) -> np.ndarray:
    e = np.clip(y, 1e-6, 1 - 1e-6)
    return np.log(e / (1 - e))


def read_sog(path: str | os.PathLike) -> GaussianCloud:
    """Return the Gaussians of a ``.sog`` zip or of a SOG ``meta.json`` (textures beside it).

    Raises:
        FormatError: not a zip / JSON, missing meta.json or texture, a texture that is not WebP or too small for
            the count, an unsupported SOG version, malformed metadata.
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

        def load(name: str) -> bytes:
            try:
                return zf.read(base + name)
            except KeyError:
                raise _fail(p, f"SOG zip lacks {base + name!r} named in meta.json") from None
            except (zipfile.BadZipFile, OSError, EOFError) as exc:
                raise _fail(p, f"SOG zip entry {name!r} is corrupt ({exc})") from None

        meta_bytes = load("meta.json")
    else:
        folder = p.parent

        def load(name: str) -> bytes:
            f = folder / name
            if not f.is_file():
                raise _fail(p, f"SOG texture {name!r} named in meta.json is missing beside it")
            return f.read_bytes()

        meta_bytes = p.read_bytes()
    try:
        meta = json.loads(meta_bytes.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _fail(p, f"SOG meta.json is not valid JSON ({exc})") from None
    try:
        return _decode(p, meta, load)
    except (KeyError, TypeError, IndexError, ValueError) as exc:
        raise _fail(p, f"SOG meta.json is malformed ({type(exc).__name__}: {exc})") from None


def _texture(p: Path, load: Callable[[str], bytes], name: str, count: int) -> np.ndarray:
    """Return the first ``count`` RGBA pixels ``[count, 4]`` of a WebP texture, row-major."""
    from PIL import Image, UnidentifiedImageError

    data = load(name)
    try:
        with Image.open(io.BytesIO(data)) as im:
            if im.format != "WEBP":
                raise _fail(p, f"SOG texture {name!r} is {im.format}, not WebP")
            rgba = np.asarray(im.convert("RGBA"))
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise _fail(p, f"SOG texture {name!r} is not a readable WebP image ({exc})") from None
    flat = rgba.reshape(-1, 4)
    if len(flat) < count:
        raise _fail(p, f"SOG texture {name!r} has {len(flat)} pixels, fewer than the {count} Gaussians")
    return flat[:count].astype(np.int64)


def _decode(p: Path, meta: dict, load: Callable[[str], bytes]) -> GaussianCloud:
    version = meta.get("version")
    if version not in (None, 2):
        raise _fail(p, f"SOG version {version} is not supported (1 or 2)")
    count = int(meta["count"]) if version == 2 else int(meta["means"]["shape"][0])
    if count <= 0 or count > _MAX_COUNT:
        raise _fail(p, f"SOG count {count} is out of range")
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
        from PIL import Image

        cdata = load(centroids_name)
        with Image.open(io.BytesIO(cdata)) as im:
            cw, chh = im.size
        cen = _texture(p, load, centroids_name, cw * chh).reshape(chh, cw, 4)
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
