"""Decoding a dataset's photos, masks and depths: as stored, checked against the memory available, and reduced to the
loaded size a strip of rows at a time (:class:`_ViewStack`). The loaders of :mod:`roodi_toolkit.io.blender` and
:mod:`roodi_toolkit.io.colmap` use these through :mod:`roodi_toolkit.io.dataset`, which re-exports them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
import torch

from ..errors import DatasetError, RoodiError
from ..limits import check_memory
from .files import open_image, read_image

if TYPE_CHECKING:
    from .dataset_core import _Crop


def _to_float_image(arr: np.ndarray, path: Path, grey: bool = False) -> Any:
    """Return (rgb [H, W, 3] float32, alpha [H, W] float32 or None) from a uint8/uint16 (or 1-bit) image array;
    with ``grey``, the one channel ``[H, W]`` of an ``[H, W, 1]`` array."""
    if arr.dtype == np.bool_:  # a 1-bit image as stored: 0 and 1, as 0 and 255 divided by 255
        scale = 1.0
    elif arr.dtype == np.uint16:
        scale = 65535.0
    elif arr.dtype == np.uint8:
        scale = 255.0
    else:
        raise DatasetError(f"{path}: unsupported image data type {arr.dtype}")
    img = arr.astype(np.float32) / scale
    if grey:
        return img[..., 0]
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=2), None
    if img.shape[2] == 4:
        return img[..., :3], img[..., 3]
    if img.shape[2] == 3:
        return img, None
    raise DatasetError(f"{path}: expected a grey, RGB or RGBA image, got {img.shape[2]} channels")


def _read_rgb(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    return _to_float_image(_read_dataset_image(path), path)


def _image_size(path: Path) -> tuple[int, int]:
    """Return an image file's (width, height) from its header, without decoding it (refused in one line if it is
    unreadable or too large for the memory available)."""
    try:
        with open_image(path) as img:
            return int(img.size[0]), int(img.size[1])
    except RoodiError as exc:
        raise DatasetError(str(exc)) from None


_STRIP_BYTES = 32 << 20  # float32 working memory of one strip of rows of a full-size image


def _nearest_indices(n_in: int, n_out: int) -> np.ndarray:
    """Return the source index of each of ``n_out`` samples that nearest-exact resizing from ``n_in`` takes: the
    very indices ``torch.nn.functional.interpolate(mode="nearest-exact")`` uses (it is asked, on an index ramp)."""
    ramp = torch.arange(n_in, dtype=torch.float32).reshape(1, 1, n_in, 1)
    picked = torch.nn.functional.interpolate(ramp, size=(n_out, 1), mode="nearest-exact")
    return picked.reshape(-1).to(torch.int64).numpy()


def _row_bins(n_in: int, n_out: int) -> tuple[int, int]:
    """Return (output rows, input rows) of one period of area resizing from ``n_in`` rows to ``n_out``: the bins
    ``[floor(i * n_in / n_out), ceil((i + 1) * n_in / n_out))`` repeat every such many rows, so a strip of whole
    periods resizes exactly as the whole image would."""
    g = math.gcd(n_in, n_out)
    return n_out // g, n_in // g


class _ViewStack:
    """Decodes a dataset's images one at a time straight to the training size, so memory follows that size.

    Each image is decoded as stored (1 to 8 bytes a pixel) and turned into float32 a strip of rows at a time: each
    strip is composited on the background (alpha and colour area-averaged afterwards give the same result as
    averaging first, as compositing is linear), cut to the common size (:class:`~roodi_toolkit.io.dataset._Crop`)
    and area-resized into its rows of the ``[N, h, w, 3]`` tensor. The strips hold whole periods of the resize's
    bins, so the result is bitwise what resizing the whole float image gives, without ever holding it (a
    13300x13300 photo trained at ``--downscale 250`` needs its 177-530 MB of stored pixels, not 4.8 GB). Masks and
    depths are resized with nearest-exact sampling, taken straight from the stored values.
    """

    def __init__(self, crop: _Crop, size: tuple[int, int], background: Sequence[float]) -> None:
        self.crop, self.size = crop, size  # size: (width, height) after downscaling
        self.bg = np.asarray(background, np.float32)
        n = len(crop.offsets)
        # colour, alpha, a mask and a depth per pixel of every view, at the reduced size
        check_memory(28.0 * n * size[0] * size[1], f"the dataset's {n} images at {size[0]}x{size[1]} pixels",
                     "reduce them with --downscale (or a smaller images_N folder)", DatasetError)
        self.rgb = torch.empty(n, size[1], size[0], 3, dtype=torch.float32)
        self.alpha: torch.Tensor | None = None  # made at the first image with alpha: ones for views without
        self.masks: list[torch.Tensor | None] = []
        self.depths: list[torch.Tensor | None] = []

    def _fit(self, arr: np.ndarray, index: int, mode: str) -> torch.Tensor:
        x0, y0 = self.crop.offsets[index]
        arr = arr[y0:y0 + self.crop.height, x0:x0 + self.crop.width]
        t = torch.from_numpy(np.ascontiguousarray(arr))
        w, h = self.size
        if (w, h) == (self.crop.width, self.crop.height):
            return t
        return _resize_stack(t[None], (h, w), mode)[0]

    def _sample(self, arr: np.ndarray, index: int) -> np.ndarray:
        """Return the nearest-exact samples of a stored mask or depth ``[H, W]`` at the reduced size (cropped)."""
        x0, y0 = self.crop.offsets[index]
        w, h = self.size
        rows = y0 + _nearest_indices(self.crop.height, h)
        cols = x0 + _nearest_indices(self.crop.width, w)
        return arr[np.ix_(rows, cols)]

    def _add_strips(self, stored: np.ndarray, path: Path, index: int) -> None:
        """Put the stored image's composited, cropped, area-resized pixels in view ``index``, a strip at a time."""
        x0, y0 = self.crop.offsets[index]
        cw, ch = self.crop.width, self.crop.height
        w, h = self.size
        per_row = cw * 16  # float32 colour and alpha of one row
        if (w, h) == (cw, ch):
            period_out = period_in = 1
        else:
            period_out, period_in = _row_bins(ch, h)
            if period_in * per_row > _STRIP_BYTES:  # no short period: one output row (one bin of rows) at a time
                period_out = period_in = 0
        step = max(1, _STRIP_BYTES // max(1, period_in * per_row)) * period_out if period_out else 1
        i = 0
        while i < h:
            j = min(h, i + step)
            r0, r1 = (i * ch) // h, -((-j * ch) // h)  # the input rows of output rows [i, j)
            block = stored[y0 + r0:y0 + r1, x0:x0 + cw]
            if block.ndim == 2:  # grey: one channel resized, then given to all three (the same numbers)
                grey = _to_float_image(block[..., None], path, grey=True)
                grey_t = torch.from_numpy(np.ascontiguousarray(grey))
                if (w, h) != (cw, ch):
                    grey_t = _resize_stack(grey_t[None], (j - i, w), "area")[0]
                self.rgb[index, i:j] = grey_t[..., None].expand(-1, -1, 3)
                i = j
                continue
            rgb, alpha = _to_float_image(block, path)
            if alpha is not None:
                rgb = rgb * alpha[..., None] + self.bg * (1.0 - alpha[..., None])
                if self.alpha is None:
                    self.alpha = torch.ones(self.rgb.shape[:3], dtype=torch.float32)
            rgb_t = torch.from_numpy(np.ascontiguousarray(rgb.astype(np.float32)))
            alpha_t = None if alpha is None else torch.from_numpy(np.ascontiguousarray(alpha.astype(np.float32)))
            if (w, h) != (cw, ch):
                rgb_t = _resize_stack(rgb_t[None], (j - i, w), "area")[0]
                alpha_t = None if alpha_t is None else _resize_stack(alpha_t[None], (j - i, w), "area")[0]
            self.rgb[index, i:j] = rgb_t
            if alpha_t is not None:
                self.alpha[index, i:j] = alpha_t
            i = j

    def add(self, path: Path, index: int, mask: np.ndarray | None = None, depth: np.ndarray | None = None, *,
            undistort: Any = None) -> None:
        """Decode ``path`` (view ``index``) and keep it at the reduced size, with its mask and depth if given;
        ``undistort`` maps the decoded full-size image (and its alpha) onto a pinhole camera's first."""
        if undistort is not None:  # the remap needs the whole float image
            rgb, alpha = _read_rgb(path)
            rgb = undistort(rgb)
            alpha = None if alpha is None else undistort(alpha)
            if alpha is not None:
                rgb = rgb * alpha[..., None] + self.bg * (1.0 - alpha[..., None])
            self.rgb[index] = self._fit(rgb.astype(np.float32), index, "area")
            if alpha is not None:
                if self.alpha is None:
                    self.alpha = torch.ones(self.rgb.shape[:3], dtype=torch.float32)
                self.alpha[index] = self._fit(alpha.astype(np.float32), index, "area")
        else:
            self._add_strips(_read_stored(path), path, index)
        self.masks.append(None if mask is None else torch.from_numpy(self._sample(mask, index).astype(np.int64)))
        self.depths.append(None if depth is None else
                           torch.from_numpy(np.ascontiguousarray(self._sample(depth, index), dtype=np.float32)))

    def images(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Return images ``[N, h, w, 3]`` and alphas ``[N, h, w]`` (ones for views without alpha), or None."""
        return self.rgb, self.alpha


def _read_dataset_image(path: Path) -> np.ndarray:
    """Return an image file's array, its read errors as DatasetError."""
    try:
        return read_image(path)
    except RoodiError as exc:
        raise DatasetError(str(exc)) from None


def _read_stored(path: Path) -> np.ndarray:
    """Return a dataset photo's pixels as stored (bool for 1-bit, uint8 or uint16; grey ``[H, W]``, colour
    ``[H, W, 3|4]``), read-only and without the copy :func:`read_image` makes."""
    try:
        with open_image(path) as img:
            if img.mode in ("1", "L", "RGB", "RGBA", "I;16", "I;16B", "I;16L", "I;16N"):
                try:
                    arr = np.asarray(img)
                except (OSError, SyntaxError, ValueError, EOFError) as exc:
                    raise DatasetError(f"{path}: cannot read image ({' '.join(str(exc).split())[:200]})") from None
                return arr.astype(np.uint16, copy=False) if arr.dtype not in (np.uint8, np.bool_) else arr
    except RoodiError as exc:
        raise DatasetError(str(exc)) from None
    return _read_dataset_image(path)  # other modes: converted by read_image


def _read_mask(path: Path) -> np.ndarray:
    """Return a mask's instance ids ``[H, W]`` as stored (uint8 or uint16; the first channel of an RGB(A) mask)."""
    arr = _read_dataset_image(path)
    if arr.ndim == 3:
        # an RGB(A) mask: instance ids are stored in the first channel
        arr = arr[..., 0]
    return arr


def _read_depth(path: Path, scale: float) -> np.ndarray:
    if path.suffix.lower() == ".npy":
        arr = _load_npy(path, "depth")
        if arr.ndim == 3 and arr.shape[2] == 1:
            arr = arr[..., 0]
        if arr.ndim != 2:
            raise DatasetError(f"{path}: depth must be a 2-D array [H, W], got shape {list(arr.shape)}")
        if arr.dtype.kind not in "fiub":
            raise DatasetError(f"{path}: depth must hold real numbers, got {arr.dtype}")
        return np.asarray(arr, dtype=np.float32)
    arr = _read_dataset_image(path)
    if arr.ndim == 3:
        arr = arr[..., 0]
    return arr.astype(np.float32) * np.float32(scale)


def _load_npy(path: Path, what: str) -> np.ndarray:
    """Return a ``.npy`` array: mapped first, so a header that claims more than the file holds is refused before
    anything is allocated, then copied into memory if it fits."""
    try:
        mapped = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError, SyntaxError) as exc:
        raise DatasetError(f"{path}: cannot read {what} ({' '.join(str(exc).split())[:200]})") from None
    if not isinstance(mapped, np.ndarray):
        if hasattr(mapped, "close"):
            mapped.close()
        raise DatasetError(f"{path}: {what} is not a .npy array (an .npz archive?); save one array with numpy.save")
    check_memory(mapped.nbytes, f"{path}: this {what}", "make it smaller first", DatasetError)
    try:
        return np.array(mapped)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read {what} ({' '.join(str(exc).split())[:200]})") from None


def _resize_stack(images: torch.Tensor, size: tuple[int, int], mode: str) -> torch.Tensor:
    """Resize ``[N, H, W, C]`` or ``[N, H, W]`` to ``size`` (height, width)."""
    squeeze = images.ndim == 3
    x = images[..., None] if squeeze else images
    x = x.permute(0, 3, 1, 2)
    dtype = x.dtype
    if mode == "nearest":
        # "nearest-exact" samples pixel centres: the one that keeps instance ids on the same pixel grid
        out = torch.nn.functional.interpolate(x.float(), size=size, mode="nearest-exact").to(dtype)
    else:
        out = torch.nn.functional.interpolate(x, size=size, mode="area")
    out = out.permute(0, 2, 3, 1)
    return out[..., 0] if squeeze else out.contiguous()
