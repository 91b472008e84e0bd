"""3D completion from the object itself: mirror symmetry about one of its principal planes, and a wall of new
Gaussians from its lowest seen part down to the surface it stands on.

Many objects people extract (bottles, mugs, bowls, chairs, balls, baskets) are mirror-symmetric, and the part that no
training view saw is often the mirror image of a part that one did. :func:`find_mirror` tries the planes
perpendicular to the principal axes of the object's Gaussians (PCA of their means, weighted by opacity), and to the
scene's up axis and the horizontal principal axes when the up axis is known, each at offsets along its normal
(the centroid of a partly seen object is off its plane of symmetry), hill-climbs the best planes' normals and offsets
(the principal axes of a partly seen object are tilted), and keeps the plane whose mirrored copy best agrees with the
seen part: the opacity-weighted share of mirrored Gaussians that land within a few Gaussian spacings
of an original one of a similar colour. On a partly seen object this measure leans a little towards planes through
the seen part (they map more of it onto itself): the removed cap of an ellipsoid 1.2 long, 37% of its surface,
puts the plane about 0.05 off its true place (tests/pipeline/test_fill.py). :func:`mirror_cloud` reflects means,
rotations (a reflection composed with a flip of one local axis, so that the rotation stays proper and the covariance
is the mirror image) and keeps the base colour (higher SH bands are dropped: their mirror image is not a rotation of
them).

A part hidden on every side (a bottle's lower half in a sleeve, a pot in a box) has no seen mirror image: below the
lowest seen part the object is completed down to the surface it stands on (:mod:`roodi_toolkit.pipeline.support`:
a wall of new Gaussians, or copies of the lowest band where no wall fits).

:class:`SymmetryInpainter` makes this completion first (:meth:`SymmetryInpainter.complete`, before the refinement
chooses its views, which then frame the completed object), drops what a training view sees through
(``FillContext.seen_empty``), renders the object with it into the views and takes that render in the masked pixels
it covers; a 2D inpainter (``exemplar`` by default) fills only the holes left inside the completed silhouette and
what the scene hides. The completion's Gaussians that land where the object has none are proposed
(:attr:`~roodi_toolkit.pipeline.inpaint.FillContext.proposed`) and the refinement adds them before fine-tuning.
Measured on the occluded presets (``benchmarks/RESULTS.md``, "Completing what no view saw (issue 37)"). Without a
context it is the 2D fallback alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import torch
from scipy.ndimage import binary_fill_holes
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from torch import Tensor

from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..params import GaussianParams
from .inpaint import FillContext, Inpainter, get_inpainter, to_grid
from .support import _spacing, extrude_to_support, shell_to_support


@dataclass(frozen=True)
class Mirror:
    """A plane of symmetry ``normal . x = offset`` and how well the object agrees with its mirror image.

    Attributes:
        normal: unit normal. [3]
        offset: signed distance of the plane from the origin along ``normal``.
        agreement: opacity-weighted share of mirrored Gaussians that land near an original one of similar colour.
    """

    normal: np.ndarray
    offset: float
    agreement: float


def mirror_cloud(cloud: GaussianCloud, normal: Sequence[float], offset: float) -> GaussianCloud:
    """Return ``cloud`` reflected about the plane ``normal . x = offset`` (base colour kept, higher SH bands zeroed).

    Example:
        >>> c = GaussianCloud.from_activated(np.array([[2.0, 1.0, 0.0]]), scales=np.array([[0.3, 0.1, 0.1]]),
        ...     opacities=np.array([0.5]), rgb=np.array([[0.2, 0.4, 0.6]]))
        >>> m = mirror_cloud(c, [1, 0, 0], 0.5)
        >>> m.means.tolist(), np.round(m.covariances(), 3).tolist() == np.round(c.covariances(), 3).tolist()
        ([[-1.0, 1.0, 0.0]], True)
    """
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    house = np.eye(3) - 2 * np.outer(n, n)
    means = cloud.means.astype(np.float64)
    mirrored = means - 2 * ((means @ n) - offset)[:, None] * n
    # H R has determinant -1; H R D with D = diag(-1, 1, 1) is a proper rotation and D S^2 D = S^2, so the
    # covariance (H R D) S^2 (H R D)^T = H Sigma H is the mirror image
    rot = house[None] @ cloud.rotations() @ np.diag([-1.0, 1.0, 1.0])[None]
    xyzw = Rotation.from_matrix(rot).as_quat()
    out = cloud.copy()
    out.means = mirrored.astype(np.float32)
    out.quats_wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1).astype(np.float32)
    out.sh_rest = np.zeros_like(cloud.sh_rest)
    if out.normals is not None:
        out.normals = (cloud.normals.astype(np.float64) @ house).astype(cloud.normals.dtype)
    return out


def find_mirror(cloud: GaussianCloud, *, up: Optional[Sequence[float]] = None, offsets: int = 21,
                max_points: int = 1500, colour_tolerance: float = 0.15, refine: int = 2, seed: int = 0) -> Mirror:
    """Return the candidate plane of symmetry whose mirror image of ``cloud`` agrees best with it (module docstring).

    Args:
        cloud: the object's Gaussians.
        up: the scene's up axis, if known (adds it and the horizontal principal axes as candidate normals). [3]
        offsets: offsets tried per normal, evenly over +-0.4 of the object's extent along it.
        refine: hill-climb the normal (from 16 degrees down to 1) and offset of this many best planes.
        max_points: score with at most this many Gaussians (a seeded subset beyond).
        colour_tolerance: largest max-channel colour difference of a matching pair.
        seed: seeds the subset.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> p = rng.normal(size=(3000, 3))
        >>> p = p / np.linalg.norm(p, axis=1, keepdims=True) * [1.0, 0.6, 0.4]  # an ellipsoid's surface
        >>> p = p[p[:, 0] < 0.5]  # its +x end never seen
        >>> rgb = np.stack([p[:, 1] + 0.5, p[:, 2] + 0.5, np.full(len(p), 0.5)], 1)  # colour breaks y and z
        >>> c = GaussianCloud.from_activated(p + [5.0, 0, 0], scales=np.full((len(p), 3), 0.02),
        ...     opacities=np.full(len(p), 0.9), rgb=rgb)
        >>> m = find_mirror(c)
        >>> round(abs(float(m.normal[0])), 2), abs(float(m.offset * np.sign(m.normal[0])) - 5.0) < 0.15
        (1.0, True)
    """
    if len(cloud) < 4:
        raise ConfigError(f"symmetry: the object has {len(cloud)} Gaussians; at least 4 are needed to find a plane")
    means = cloud.means.astype(np.float64)
    w = cloud.opacities.astype(np.float64)
    rgb = cloud.rgb.astype(np.float64)
    rng = np.random.default_rng(seed)
    pick = np.arange(len(means)) if len(means) <= max_points else rng.choice(len(means), max_points, replace=False)
    centre = (w[:, None] * means).sum(0) / max(w.sum(), 1e-12)
    cov = np.cov((means - centre).T, aweights=np.maximum(w, 1e-6))
    axes = list(np.linalg.eigh(cov)[1].T)
    if up is not None:
        u = np.asarray(up, np.float64)
        u = u / np.linalg.norm(u)
        flat = (means - centre) - np.outer((means - centre) @ u, u)
        hax = np.linalg.eigh(np.cov(flat.T, aweights=np.maximum(w, 1e-6)))[1].T
        axes += [u] + [a for a in hax if abs(a @ u) < 0.5]
    tree = cKDTree(means)
    tol = 2.0 * _spacing(means[pick])

    def agreement(n: np.ndarray, off: float) -> float:
        p = means[pick]
        q = p - 2 * ((p @ n) - off)[:, None] * n
        d, j = tree.query(q, distance_upper_bound=tol)
        hit = np.isfinite(d)
        hit[hit] &= np.abs(rgb[j[hit]] - rgb[pick][hit]).max(axis=1) <= colour_tolerance
        return float((w[pick] * hit).sum() / max(w[pick].sum(), 1e-12))

    found = []
    for a in axes:
        n = a / np.linalg.norm(a)
        proj = means @ n
        lo, hi = np.quantile(proj, [0.02, 0.98])
        mid, span = (lo + hi) / 2, hi - lo
        cands = mid + np.linspace(-0.4, 0.4, offsets) * span
        scores = [agreement(n, o) for o in cands]
        k = int(np.argmax(scores))
        found.append((scores[k], n, float(cands[k]), max(span, 1e-9)))
    found.sort(key=lambda f: -f[0])
    best = Mirror(np.array([1.0, 0, 0]), 0.0, -1.0)
    # the principal axes of a partly seen object are tilted: hill-climb the best few planes in angle and offset
    for score, n, off, span in found[:refine]:
        step_a, step_o = np.radians(16.0), 0.05 * span
        while step_a > np.radians(0.7):
            u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
            u /= np.linalg.norm(u)
            v = np.cross(n, u)
            moved = False
            for da in (-step_a, 0.0, step_a):
                for db in (-step_a, 0.0, step_a):
                    m = n * np.cos(np.hypot(da, db)) + np.sin(da) * u + np.sin(db) * v
                    m /= np.linalg.norm(m)
                    for do in (-step_o, 0.0, step_o):
                        o = off + do + float((m - n) @ ((means * w[:, None]).sum(0) / max(w.sum(), 1e-12)))
                        sc = agreement(m, o)
                        if sc > score + 1e-9:
                            score, best_m, best_o, moved = sc, m, o, True
            if moved:
                n, off = best_m, best_o
            else:
                step_a, step_o = step_a / 2, step_o / 2
        if score > best.agreement:
            best = Mirror(n, float(off), float(score))
    return best


def new_gaussians(cloud: GaussianCloud, mirrored: GaussianCloud, distance: float) -> np.ndarray:
    """Return which mirrored Gaussians ``[M]`` (bool) lie farther than ``distance`` from every original one."""
    d, _ = cKDTree(cloud.means.astype(np.float64)).query(mirrored.means.astype(np.float64),
                                                          distance_upper_bound=distance)
    return ~np.isfinite(d)


class SymmetryInpainter(Inpainter):
    """Mirror-symmetry completion rendered into the views, the rest by a 2D inpainter (module docstring).

    What it can do: give the never-seen side of a mirror-symmetric object its shape and the colours of the side that
    was seen, and the part hidden all round below the seen part (a wrap, a box, a bowl) a wall that continues the
    lowest seen outline down to the support, consistently in all views (it is one 3D completion), and propose the
    Gaussians that make it so. What it cannot do: guess a shape that the seen part does not continue (a round body
    hidden below its widest part is completed as a straight wall, narrowed only where the scene's other Gaussians
    bound it; a handle or a foot that no view saw stays missing), or a colour other than the lower seen part's.

    Args:
        fallback: the registered 2D inpainter for the pixels the mirror image does not cover, and for calls without
            a context (``exemplar`` by default).
        min_agreement: use the mirror only when this share of the object agrees with its mirror image.
        alpha_threshold: a pixel is covered where the object and its mirror image render at least this alpha.
        propose: propose the mirrored Gaussians farther than ``new_distance`` (times the median spacing of the
            Gaussians) from every original one.
        new_distance: see ``propose``.
        mirror: complete by mirror symmetry (off: the part below alone).
        extrude: also complete the part below the object's lowest band down to the surface it stands on (when the
            context knows ``support``), after the mirror if one agrees.
        wall: the part below as a wall of new Gaussians (:func:`shell_to_support`); off, or where no wall fits: the
            band's copies (:func:`extrude_to_support`).
        min_around: no wall when fewer Gaussians than this, a training-view pixel apart, go round the outline.
        fallback_options: options of the fallback inpainter.
    """

    name = "symmetry"
    uses_context = True

    def __init__(self, *, fallback: str = "exemplar", min_agreement: float = 0.35, alpha_threshold: float = 0.5,
                 propose: bool = True, new_distance: float = 2.0, mirror: bool = True, extrude: bool = True,
                 wall: bool = True, min_around: int = 3, fallback_options: Optional[dict] = None) -> None:
        if fallback == self.name:
            raise ConfigError("symmetry inpainter: the fallback must be another inpainter")
        if not 0 <= min_agreement <= 1 or not 0 < alpha_threshold < 1 or new_distance <= 0:
            raise ConfigError(f"symmetry inpainter: need 0 <= min_agreement <= 1, 0 < alpha_threshold < 1 and "
                              f"new_distance > 0; got {min_agreement}, {alpha_threshold}, {new_distance}")
        self.fallback = get_inpainter(fallback, **(fallback_options or {}))
        self.min_agreement = float(min_agreement)
        self.alpha_threshold = float(alpha_threshold)
        self.propose = bool(propose)
        self.new_distance = float(new_distance)
        self.mirror, self.extrude, self.wall, self.min_around = bool(mirror), bool(extrude), bool(wall), int(min_around)
        self.last_mirror: Optional[Mirror] = None
        self.last_extruded = 0
        self._completed: Optional[tuple[FillContext, Optional[GaussianCloud]]] = None

    def complete(self, context: FillContext) -> Optional[GaussianCloud]:
        """Return the completion's Gaussians (mirror image, then the wall or the copies down to the support), less
        what a training view sees through, or None when nothing applies (no plane agrees well enough and no support
        is known) or nothing is left. Needs only the context's object, ``up``, ``support`` and ``seen_empty``."""
        if self._completed is not None and self._completed[0] is context:
            return self._completed[1]
        cloud = context.object_cloud
        result = None
        self.last_extruded = 0
        if len(cloud) >= 4:
            parts = []
            if self.mirror:
                plane = find_mirror(cloud, up=context.up)
                self.last_mirror = plane
                if plane.agreement >= self.min_agreement:
                    parts.append(mirror_cloud(cloud, plane.normal, plane.offset))
            if self.extrude and context.up is not None and context.support is not None:
                joined = GaussianCloud.concatenate([cloud, *parts])
                extruded = joined.select(np.zeros(len(joined), dtype=bool))
                if self.wall:
                    extruded = shell_to_support(joined, context.up, context.support, min_spacing=context.pixel or 0.0,
                                                obstacles=context.obstacles, min_around=self.min_around)
                if not len(extruded):  # no wall (the object a few pixels wide, or no room left round it): copies
                    extruded = extrude_to_support(joined, context.up, context.support)
                self.last_extruded = len(extruded)
                parts.append(extruded)
            parts = [p for p in parts if len(p)]
            if parts:
                result = GaussianCloud.concatenate(parts)
                if context.seen_empty is not None:
                    # what a training view sees through is not part of the object, whatever the completion says
                    result = result.select(~np.asarray(context.seen_empty(result.means.astype(np.float64)), bool))
                result = result if len(result) else None
        self._completed = (context, result)
        return result

    def mirror_views(self, context: FillContext) -> Optional[tuple[Tensor, Tensor, GaussianCloud]]:
        """Return the object with its completion (:meth:`complete`, or the context's ``completion`` when the
        refinement made it first) rendered in the context's views (rgb ``[V, H, W, 3]``, alpha ``[V, H, W]``) and
        the completion's Gaussians, or None when there is no completion."""
        mirrored = context.completion if context.completion is not None else self.complete(context)
        if mirrored is None:
            return None
        both = GaussianParams.from_cloud(GaussianCloud.concatenate([context.object_cloud, mirrored]))
        bg = torch.as_tensor(context.background, dtype=torch.float32)
        rgb, alpha = [], []
        with torch.no_grad():
            for cam in context.cameras:
                out = context.renderer.render(both, cam, background=bg)
                rgb.append(out.rgb.clamp(0, 1))
                alpha.append(out.alpha[..., 0])
        return torch.stack(rgb), torch.stack(alpha), mirrored

    def fill(self, images: Tensor, masks: Tensor, prompt: str,  # type: ignore[override]
             context: Optional[FillContext] = None) -> Tensor:
        if context is not None:
            context.proposed = None
        views = None
        if context is not None and images.shape[0] == 1 and len(context.cameras) == context.rows * context.cols:
            cam = context.cameras[0]
            if images.shape[1:3] == (context.rows * cam.height, context.cols * cam.width):
                views = self.mirror_views(context)
        out = images.clone()
        rest = masks.clone()
        if views is not None:
            rgb, alpha, mirrored = views
            grid_rgb = to_grid(rgb, context.rows, context.cols)[None]
            covered = masks & (to_grid(alpha, context.rows, context.cols)[None] >= self.alpha_threshold)
            out = torch.where(covered[..., None], grid_rgb, out)
            # the 2D fallback only where the completed object has a hole or the scene hides it: round the
            # completed silhouette the background stays (exemplar patches there are not the object's)
            shown = ~masks | covered
            inside = torch.from_numpy(np.stack([binary_fill_holes(m) for m in shown.numpy()])) & ~shown
            if context.occlusion is not None:
                inside |= to_grid(context.occlusion.occluded, context.rows, context.cols)[None]
            rest = masks & ~covered & inside
            if self.propose:
                spacing = _spacing(context.object_cloud.means.astype(np.float64))
                new = new_gaussians(context.object_cloud, mirrored, self.new_distance * spacing)
                context.proposed = mirrored.select(new) if new.any() else None
        if bool(rest.any()):
            # the fallback sees the mirror's fill as known pixels, so it continues from them too
            out = torch.where(rest[..., None], self.fallback.inpaint(out, rest), out)
        return out

