"""Which parts of a target no training view sees: the never-seen masks of its object-alone test views.

A pixel of a target's test view (the object alone) is *never seen* when the surface point its centre ray hits is
seen by no training camera of the full scene: for every training camera the point is outside the image, behind the
camera, or something (another object, the ground or the target itself) lies on the segment from the camera centre to
within :data:`VISIBILITY_TOLERANCE` of the point. This is exact ray casting on the meshes the views were rendered
from (no Gaussians, no image resolution of the training views), so it says what no method could have observed.

Example:
    >>> VISIBILITY_TOLERANCE
    0.001
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..cameras import Camera
from ..io.files import write_image
from .tracer import RenderResult, _Tracer

__all__ = ["VISIBILITY_TOLERANCE", "NEVER_SEEN_DIR", "surface_points", "seen_by_any", "never_seen_masks",
           "write_never_seen", "never_seen_record"]

NEVER_SEEN_DIR = "test/never_seen"
"""Folder of a target's never-seen masks, beside its test views (relative to the target's folder)."""

VISIBILITY_TOLERANCE = 0.001
"""Metres short of the surface point at which the segment from a training camera stops: absorbs the float32 ray
casting's error on the point itself, and is well below the gap between a target and its wrap (so a wall in front of
the point is never mistaken for the point)."""


def surface_points(camera: Camera, depth: np.ndarray) -> np.ndarray:
    """Return ``[H, W, 3]`` world points of the pixel-centre rays at z-depth ``depth`` ``[H, W]`` (the tracer's depth
    map: directions with camera z = 1, so the hit is centre + depth * direction)."""
    H, W = depth.shape
    vv, uu = np.meshgrid(np.arange(H, dtype=np.float64) + 0.5, np.arange(W, dtype=np.float64) + 0.5, indexing="ij")
    pix = np.stack([uu, vv, np.ones_like(uu)], axis=-1).reshape(-1, 3)
    dirs = (pix @ np.linalg.inv(camera.K).T) @ camera.world_to_camera[:3, :3]
    return (camera.center + dirs * depth.reshape(-1, 1).astype(np.float64)).reshape(H, W, 3)


def seen_by_any(tracer: _Tracer, points: np.ndarray, cameras: Sequence[Camera],
                tolerance: float = VISIBILITY_TOLERANCE) -> np.ndarray:
    """Return ``[M]`` whether each of ``points`` ``[M, 3]`` is seen by at least one of ``cameras``.

    Args:
        tracer: the full scene (every object and the ground), as the training views were rendered.
        points: surface points.
        cameras: the training cameras.
        tolerance: the segment from a camera stops this many metres short of the point.
    """
    points = np.asarray(points, dtype=np.float64)
    seen = np.zeros(len(points), dtype=bool)
    for cam in cameras:
        todo = np.nonzero(~seen)[0]
        if not len(todo):
            break
        p = points[todo]
        pc = p @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
        z = pc[:, 2]
        in_front = z > cam.near
        uvw = pc @ cam.K.T
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = uvw[:, 0] / z, uvw[:, 1] / z
        in_frame = in_front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        idx = np.nonzero(in_frame)[0]
        if not len(idx):
            continue
        seg = p[idx] - cam.center
        length = np.linalg.norm(seg, axis=1, keepdims=True)
        seg = seg * np.clip(1.0 - tolerance / np.maximum(length, 1e-12), 0.0, None)  # stop short of the point
        blocked = tracer.occluded(np.broadcast_to(cam.center, seg.shape).copy(), seg)
        seen[todo[idx[~blocked]]] = True
    return seen


def never_seen_masks(scene, object_id: int, test_cameras: Sequence[Camera], test_renders: Sequence[RenderResult],
                     train_cameras: Sequence[Camera], tolerance: float = VISIBILITY_TOLERANCE,
                     tracer: _Tracer | None = None) -> list[np.ndarray]:
    """Return per test view the ``[H, W]`` bool mask of the target's pixels that no training camera sees.

    Args:
        scene: the scene (:class:`roodi_toolkit.synth.world.Scene`).
        object_id: the target's id.
        test_cameras: its object-alone test cameras.
        test_renders: their renders of the object alone (``ids`` and ``depth`` of the pixel-centre rays are used).
        train_cameras: the full scene's training cameras.
        tolerance: see :data:`VISIBILITY_TOLERANCE`.
        tracer: the full scene's tracer, to reuse it across targets (default: built here).
    """
    tracer = tracer or _Tracer(scene, None, True)
    out = []
    for cam, r in zip(test_cameras, test_renders):
        on_target = (r.ids == object_id) & (r.depth > 0)
        mask = np.zeros(on_target.shape, dtype=bool)
        if on_target.any():
            pts = surface_points(cam, r.depth)[on_target]
            mask[on_target] = ~seen_by_any(tracer, pts, train_cameras, tolerance)
        out.append(mask)
    return out


def write_never_seen(target_dir: Path, scene, object_id: int, test_cameras: Sequence[Camera],
                     test_renders: Sequence[RenderResult], train_cameras: Sequence[Camera],
                     frame_extra: Sequence[dict[str, Any]], tracer: _Tracer) -> dict[str, Any]:
    """Write a target's never-seen masks (uint8, 255 = never seen) under ``target_dir/NEVER_SEEN_DIR``, add each
    frame's ``never_seen_path`` to ``frame_extra``, and return the target's scene.json entries (folder, share,
    pixel counts)."""
    masks = never_seen_masks(scene, object_id, test_cameras, test_renders, train_cameras, tracer=tracer)
    (target_dir / NEVER_SEEN_DIR).mkdir(parents=True, exist_ok=True)
    for cam, m, e in zip(test_cameras, masks, frame_extra):
        write_image(m.astype(np.uint8) * 255, target_dir / NEVER_SEEN_DIR / f"{cam.name}.png")
        e["never_seen_path"] = f"{NEVER_SEEN_DIR}/{cam.name}.png"
    on = int(sum(int((r.ids == object_id).sum()) for r in test_renders))
    hidden = int(sum(int(m.sum()) for m in masks))
    return {"never_seen": NEVER_SEEN_DIR, "never_seen_share": round(hidden / max(on, 1), 6),
            "never_seen_pixels": hidden, "object_pixels": on}


def never_seen_record() -> dict[str, Any]:
    """Return scene.json's description of the never-seen masks."""
    return {"definition": "pixels of the object-alone test view whose pixel-centre surface point is seen by no "
                          "training camera (outside its image, behind it, or blocked short of the point by "
                          f"{VISIBILITY_TOLERANCE} m), by ray casting the meshes; share = never-seen pixels / "
                          "target pixels over all test views",
            "tolerance_m": VISIBILITY_TOLERANCE}
