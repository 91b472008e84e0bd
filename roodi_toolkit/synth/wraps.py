"""Wraps of the occluded scene variant: objects that touch a target and hide its lower part from every training view.

The occluded variant of every preset (``build_scene(..., occluded=True)``, ``make-scene --occluded``) wraps each
target in an object that touches it: a wall around the convex hull of its lower part, open at the top, or a bowl that
cradles a round object. The training cameras (elevations 18 to 65 degrees) look over the wrap's rim but never down
into the gap between wrap and target, so the target's lower part is hidden in every training view, while the
object-alone test views show it (:mod:`roodi_toolkit.synth.visibility` measures how much).

Example:
    >>> WRAP_GAP
    0.003
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import ConvexHull

from .objects import Material, Part, _matte, _mesh_arrays, _o3d, _random_color

__all__ = ["WRAPPABLE", "ROUND_KINDS", "WRAP_GAP", "WRAP_THICKNESS", "WRAP_KINDS", "wrap_parts"]

WRAPPABLE = frozenset({"mug", "bottle", "glass", "vase", "apple", "ball", "pot", "kettle", "teddy", "crate",
                       "basket", "pyvista_globe", "pyvista_nut", "plant"})
"""Target kinds of the occluded variant: compact objects whose lower part a wrap can hide (not flat or open ones,
such as plates and pans, whose hidden part would be a sliver)."""
ROUND_KINDS = frozenset({"ball", "apple"})
"""Kinds cradled in a bowl rather than boxed or sleeved."""
WRAP_GAP = 0.003
"""Clearance in metres between a wrap and its target: small, so no training ray reaches down the gap."""
WRAP_THICKNESS = 0.008
WRAP_KINDS = ("open_box", "sleeve", "bowl_wrap")
"""The kinds a wrap is recorded as in scene.json."""


def _hull_wall(points_xy: np.ndarray, offset: float, thickness: float, height: float, mat: Material) -> Part:
    """Return a wall ``height`` high standing on z = 0 around the convex hull of ``points_xy`` ``[P, 2]`` grown by
    ``offset``: inner and outer faces ``thickness`` apart and the rim between them; no floor, no lid."""
    ring = np.linspace(0, 2 * math.pi, 24, endpoint=False)
    disc = np.stack([np.cos(ring), np.sin(ring)], axis=1)
    grown = (points_xy[:, None, :] + offset * disc[None]).reshape(-1, 2)  # Minkowski sum with a 24-gon
    hull = ConvexHull(grown)
    inner = grown[hull.vertices]  # counter-clockwise
    edge = np.roll(inner, -1, axis=0) - inner
    en = np.stack([edge[:, 1], -edge[:, 0]], axis=1)  # outward edge normals of a counter-clockwise polygon
    en /= np.maximum(np.linalg.norm(en, axis=1, keepdims=True), 1e-12)
    vn = en + np.roll(en, 1, axis=0)  # vertex normals: mean of the two edges' normals
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
    outer = inner + thickness * vn
    n = len(inner)
    z0, z1 = np.zeros((n, 1)), np.full((n, 1), height)
    # vertex rings: inner bottom, inner top, outer top, outer bottom
    v = np.concatenate([np.hstack([inner, z0]), np.hstack([inner, z1]), np.hstack([outer, z1]),
                        np.hstack([outer, z0])])
    i, j = np.arange(n), (np.arange(n) + 1) % n
    tris = []
    for a, b in ((0, 1), (1, 2), (2, 3)):  # inner face, rim, outer face: quads between consecutive rings
        tris += [np.stack([a * n + i, a * n + j, b * n + j], 1), np.stack([a * n + i, b * n + j, b * n + i], 1)]
    return Part(v, np.concatenate(tris).astype(np.int64), mat, False)


def wrap_parts(kind: str, target: list[Part], rng: np.random.Generator) -> tuple[str, list[Part]]:
    """Return the kind and parts (local coordinates, like ``target``'s) of a wrap that touches the target.

    ``ball`` and ``apple`` sit in a bowl whose rim is above their equator (``bowl_wrap``); anything else stands in
    a wall around the convex hull of its lower part, :data:`WRAP_GAP` away, open at the top (an ``open_box`` when
    the hull is a box's, a ``sleeve`` otherwise). The rim is at ``rng``-drawn 62 to 75 % of the target's height.

    Args:
        kind: the target's kind.
        target: its parts, standing on z = 0 around the z axis.
        rng: the scene's generator.
    """
    v = np.concatenate([p.vertices for p in target])
    lo, hi = v.min(axis=0), v.max(axis=0)
    h = float(hi[2] - lo[2])
    frac = float(rng.uniform(0.62, 0.75))
    mat = _matte(_random_color(rng, sat=(0.2, 0.6), val=(0.35, 0.7)), color2=_random_color(rng, val=(0.25, 0.45)),
                 pattern=str(rng.choice(["plain", "noise", "stripes"])), pattern_scale=float(rng.uniform(15, 30)))
    g = WRAP_GAP
    if kind in ROUND_KINDS:
        # a bowl: the lower part of a sphere about the object's centre, its rim at ``frac`` of the height
        c = (lo + hi) / 2
        r = float(np.linalg.norm(v - c, axis=1).max()) + g
        rim = (lo[2] + frac * h - c[2]) / r  # height of the rim on the unit sphere
        sv, st = _mesh_arrays(_o3d().geometry.TriangleMesh.create_sphere(1.0, 24))
        st = st[(sv[st][:, :, 2] <= rim + 1e-9).all(axis=1)]
        used, st = np.unique(st, return_inverse=True)  # drop the vertices above the rim (bounds, footprint)
        return "bowl_wrap", [Part(sv[used] * r + c, st.reshape(-1, 3), mat, True)]
    wall_h = frac * h
    # every triangle that reaches below the rim: the hull of their corners holds the target's part below it
    low = np.concatenate([p.vertices[np.unique(p.triangles[p.vertices[p.triangles][:, :, 2].min(axis=1) < wall_h])]
                          for p in target])
    corners = len(ConvexHull(low[:, :2]).vertices)
    wall = _hull_wall(low[:, :2], g, WRAP_THICKNESS, wall_h, mat)
    return ("open_box" if corners <= 4 else "sleeve"), [wall]
