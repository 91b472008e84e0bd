"""What each stage of an extraction will hold in memory, estimated before it starts (issue 33).

A stage that would not fit in the memory this machine has available stops before it starts, in one line that says
what it needs, what there is and what to do (``--downscale``, fewer views), instead of being killed by the system
minutes into the work. The estimates are linear in what the stage is given, with coefficients measured on the
built-in renderer (``benchmarks/bench_stage_memory.py``; figures in ``benchmarks/RESULTS.md``, "Real size"):

- a rendering and its backward pass: :data:`PASS_PER_GAUSSIAN` bytes a Gaussian (projection, depth order, tile lists,
  the gradients of every parameter) plus :data:`PASS_PER_PIXEL` a pixel (colour, alpha, depth, transmittance, the
  backward's per-pixel state), plus 8 bytes a Gaussian and a pixel for every rendered channel beyond RGB;
- what the stage keeps: masks, per-Gaussian sums, the distilled features and their Adam state.

The photos themselves are checked when they are decoded (:mod:`roodi_toolkit.io.photos`); the checks here count
what comes on top of them, against what is available when the stage starts.

Example:
    >>> render_pass_bytes(1_000_000, 800 * 800) / 2**20 > 300
    True
"""

from __future__ import annotations

from ..errors import ConfigError
from ..limits import MEMORY_SHARE, available_memory, check_memory

PASS_PER_GAUSSIAN = 450
"""Peak bytes of one rendering and its backward, per Gaussian of SH degree 0: measured 373-392 MB at 1M and 603 MB at
2M Gaussians on a 32x32 view (``benchmarks/bench_stage_memory.py``, 2026-11-28; 304 MB at 1M before the compositing's
64-byte records), rounded up (400 had left the 1M case at 0.97-1.02 of its estimate)."""

PASS_PER_PIXEL = 250
"""Peak bytes of one rendering and its backward, per pixel, the tile lists' share included: the lists grow with the
Gaussians a pixel's tile holds, so this is set by the deepest view measured (500k random Gaussians in a ball at
800x800: 333-338 MB, where 450 a Gaussian and 250 a pixel give 367 MB; the real 500k playbot at 800x800: 266 MB)."""

SH_BYTES = 24
"""Extra bytes a Gaussian per SH coefficient beyond the first: its 3 colour values and their gradients in float32."""


def render_pass_bytes(gaussians: int, pixels: int, *, sh_coeffs: int = 1, channels: int = 3) -> float:
    """Return the estimated peak bytes of one rendering of ``gaussians`` on ``pixels`` and its backward pass
    (``sh_coeffs`` SH coefficients a colour channel; ``channels`` rendered channels: 3 for RGB, the feature count
    for features)."""
    extra = max(0, channels - 3) * 8
    return (PASS_PER_GAUSSIAN + SH_BYTES * max(0, sh_coeffs - 1) + extra) * float(gaussians) \
        + (PASS_PER_PIXEL + extra) * float(pixels)


def _todo(views: int) -> str:
    return (f"make the photos smaller with --downscale 2 (a quarter of the pixels) or use fewer of the {views} "
            "views, or run it on a machine with more memory")


def check_click(gaussians: int, width: int, height: int, views: int) -> None:
    """Refuse, before it starts, a click segmentation that would not fit: a rendering of a ``width`` x ``height``
    view (the working size the click segments at) and its backward pass, one mask a view of that size and a few sums
    a Gaussian."""
    pixels = width * height
    needed = render_pass_bytes(gaussians, pixels) + views * pixels + 64.0 * gaussians
    check_memory(needed, f"the click segmentation of {gaussians:,} Gaussians on {views} views ({width}x{height})",
                 _todo(views), ConfigError)


def distill_fixed_bytes(gaussians: int, feature_dim: int, working_pixels: int) -> float:
    """Return what distillation holds besides its weight cache: the features, their gradient and Adam's two moments
    (float32), the frozen geometry, and one rendering of the features and its backward at the working size."""
    return 16.0 * feature_dim * gaussians + 60.0 * gaussians \
        + render_pass_bytes(gaussians, working_pixels, channels=feature_dim)


def check_distill(gaussians: int, feature_dim: int, working_pixels: int, views: int) -> None:
    """Refuse, before it starts, a distillation whose features and one rendering would not fit (its weight cache
    adapts to what is left: :func:`cache_bytes`)."""
    check_memory(distill_fixed_bytes(gaussians, feature_dim, working_pixels),
                 f"distilling {feature_dim} features into {gaussians:,} Gaussians", _todo(views), ConfigError)


def cache_bytes(requested_mb: float, fixed: float) -> int:
    """Return the bytes distillation's weight cache may hold: ``requested_mb``, lowered to half of what the machine
    has available beyond ``fixed`` (the rest of the stage), so that the cache never causes the shortage it is meant
    to save time with; 0 where nothing is left."""
    want = float(requested_mb) * 2**20
    room = available_memory()
    if room is None:
        return int(want)
    return int(max(0.0, min(want, 0.5 * (MEMORY_SHARE * room - fixed))))


TRAIN_PER_GAUSSIAN = 2 * 59 * 4
"""Bytes a Gaussian of SH degree 3 holds while it trains beyond its rendering pass (which counts its values and their
gradients): Adam's two moments of its 59 float32 values. A step at 1M Gaussians on a 32x32 view measured 1,049 MB
against 1,175 MB estimated (``benchmarks/bench_stage_memory.py --one train 1000000 32``)."""


def train_bytes(gaussians: int, pixels: int) -> float:
    """Return the estimated peak bytes of a training step at ``gaussians`` Gaussians of SH degree 3 on a view of
    ``pixels`` (parameters, gradients, Adam's moments and a rendering with its backward)."""
    return TRAIN_PER_GAUSSIAN * float(gaussians) + render_pass_bytes(gaussians, pixels, sh_coeffs=16)


def check_train(gaussians: int, width: int, height: int) -> None:
    """Refuse, before it starts, a training whose model at its largest (``gaussians``: the densification's cap, or
    the model it starts from when larger) would not fit with one rendering of a ``width`` x ``height`` view (the
    photos are checked when they are decoded)."""
    check_memory(train_bytes(gaussians, width * height),
                 f"training up to {gaussians:,} Gaussians on {width}x{height} views",
                 "lower the densification's cap (--cap-max), make the photos smaller with --downscale 2 (a quarter "
                 "of the pixels), or run it on a machine with more memory", ConfigError)


def check_refine(scene_gaussians: int, object_gaussians: int, views: int, width: int, height: int) -> None:
    """Refuse, before it starts, occlusion reasoning and fine-tuning that would not fit: for every training view the
    object's mask, the pixels that may hide it and the clicked masks it came from (a byte a pixel each; targets are
    made view by view), and a rendering of the scene and of the object with its backward at full size, the object's
    parameters with their gradients and Adam's moments."""
    pixels = width * height
    needed = views * pixels * 3.0 + render_pass_bytes(scene_gaussians, pixels) \
        + render_pass_bytes(object_gaussians, pixels, sh_coeffs=16) + 4 * 59 * 4.0 * object_gaussians
    check_memory(needed, f"fine-tuning the object ({object_gaussians:,} Gaussians) on {views} views of "
                 f"{width}x{height}", _todo(views), ConfigError)
