"""PyVista views of a Gaussian cloud and of what pruning removes (the histogram to tune the threshold by eye is
:mod:`roodi_toolkit.viz.histogram`'s, re-exported here).

Each Gaussian is drawn with its footprint:

- ``ellipsoids``: the surface at ``sigmas`` standard deviations of every Gaussian, a low-resolution icosphere
  transformed by ``R diag(sigmas * scale)`` in numpy (exact orientation and anisotropy, normals from the inverse
  transpose so lighting shows the shape). For small clouds (at most :data:`ELLIPSOID_MAX_GAUSSIANS`).
- ``splats``: PyVista's ``points_gaussian`` style, a screen-facing Gaussian splat whose standard deviation is the
  geometric mean of the Gaussian's two largest scales (the face-on area of the ellipsoid). Isotropic, but it draws a
  million Gaussians in a couple of seconds on a CPU.

Kept Gaussians show their own colour (SH DC, clipped to [0, 1]) with their opacity as alpha, or a quantity through a
colour map (``color_by``); the ones pruning removes are drawn in the highlight colour, unlit: the
footprint as a wireframe ellipsoid or a splat with the Gaussian's opacity (so a large floater does not hide the
object), and an opaque square of :data:`HIGHLIGHT_MARKER_PIXELS` pixels marks its centre, so a floater smaller
than a pixel still shows and its centre is exactly the highlight colour whatever the lights.

Off screen needs no display and no GPU (VTK renders through EGL or OSMesa).
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
import pyvista as pv

try:
    from vtkmodules.vtkCommonCore import vtkLogger
except ImportError:  # pragma: no cover - older VTK
    vtkLogger = None

from ..cameras import horizontal_basis
from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..settings import check_settings, documented, setting
from .histogram import distance_is_log, distance_label, histogram_figure, save_histogram  # noqa: F401 (re-exported)

if TYPE_CHECKING:  # pragma: no cover
    from ..prune.outliers import PruneReport

GLYPHS = ("auto", "ellipsoids", "splats")
SHOW = ("both", "kept", "removed")
COLOR_BY = ("rgb", "opacity", "scale", "distance")
CAMERAS = ("iso", "xy", "xz", "yz", "+x", "-x", "+y", "-y", "+z", "-z")
ELLIPSOID_MAX_GAUSSIANS = 20_000
"""``glyphs='auto'`` draws ellipsoids up to this many Gaussians (1.6 M triangles), splats above."""
ELLIPSOID_SIGMAS = 2.0
"""Ellipsoids are drawn at this many standard deviations: about the visible extent of a splat."""
HIGHLIGHT_MARKER_PIXELS = 4.0
"""Side of the opaque square marking each removed Gaussian's centre, in pixels."""
HIGHLIGHT_WIREFRAME_OPACITY = 0.35
"""Opacity of the removed Gaussians' ellipsoid wireframes."""
DEFAULT_WINDOW_SIZE = (1024, 768)
DEFAULT_BACKGROUND = "#1c1c20"
"""Dark and neutral: no Gaussian colour or highlight is lost against it."""
VIEW_ANGLE_DEG = 30.0
"""VTK's default vertical view angle."""
ROBUST_QUANTILE = 0.005
"""The framed box spans these quantiles of the kept centres, so stray Gaussians do not shrink the object."""


@documented
@dataclass(frozen=True)
class InspectView:
    """How :func:`plot_cloud` draws the cloud (``roodi-toolkit inspect``'s view options are made from these fields)."""

    show: str = setting("both", "Which Gaussians to draw.", choices=SHOW)
    color_by: str = setting("rgb", "rgb: own colour (SH DC) with opacity as alpha; opacity, scale (largest axis) or "
                            "distance (what the prune judged: the blob score of the local tests, or the statistical "
                            "rule's mean distance to the K neighbours on a log colour bar) through a colour map.",
                            choices=COLOR_BY)
    highlight: str = setting("red", "Colour of the Gaussians pruning removes (a name or #rrggbb); 'none' draws them "
                             "like the kept.", metavar="COLOR")
    glyphs: str = setting("auto", "ellipsoids: oriented, scaled ellipsoids (exact footprint, small clouds); splats: "
                          "Gaussian point splats sized by scale (fast); auto: ellipsoids up to 20,000 drawn "
                          "Gaussians.", choices=GLYPHS)
    camera: str = setting("iso", "View direction of the window and --view-png: iso (from above, diagonally, on the "
                          "cloud's up), xy (from +z), xz (from -y), yz (from +x), or the side the camera sits on: +x, "
                          "-x, +y, -y, +z, -z. The camera frames the kept Gaussians.", choices=CAMERAS)

    def __post_init__(self) -> None:
        check_settings(self)

_DIRECTIONS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    # name: (direction from the focal point to the camera, view up); z is up, as make-scene scenes stand on z=0
    "iso": ((1.0, 1.0, 1.0), (0.0, 0.0, 1.0)),
    "+x": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "-x": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "+y": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "-y": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "+z": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "-z": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
}
_DIRECTIONS["xy"] = _DIRECTIONS["+z"]  # the xy plane seen from above
_DIRECTIONS["xz"] = _DIRECTIONS["-y"]  # the xz plane seen from the front: x right, z up
_DIRECTIONS["yz"] = _DIRECTIONS["+x"]  # the yz plane seen from +x


# ------------------------------------------------------------------------------------------------------ helpers
def _check_choice(value: str, choices: Sequence[str], name: str) -> str:
    if value not in choices:
        raise ConfigError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    return value


def display_available() -> bool:
    """Return whether an interactive window can open (an X11 or Wayland display on Linux; assumed elsewhere)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _quiet_vtk() -> None:
    """Silence VTK's stderr log (it warns about the missing X server before falling back to EGL)."""
    if vtkLogger is not None:
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)


def distances_per_gaussian(report: "PruneReport", n: int | None = None) -> np.ndarray:
    """Return ``[N]`` float64 mean neighbour distances from a prune report, NaN for Gaussians the filters dropped.

    Args:
        report: the report of :func:`~roodi_toolkit.prune.outliers.remove_statistical_outliers`.
        n: the input cloud's size (defaults to ``report.input_count``).
    """
    n = report.input_count if n is None else int(n)
    out = np.full(n, np.nan)
    out[np.asarray(report.evaluated, dtype=np.int64)] = report.mean_distances
    return out


def footprint_scales(cloud: GaussianCloud) -> np.ndarray:
    """Return ``[N]`` float32 splat standard deviations: the geometric mean of each Gaussian's two largest scales."""
    s = np.sort(cloud.scales.astype(np.float64), axis=1)
    return np.sqrt(s[:, 1] * s[:, 2]).astype(np.float32)


def robust_bounds(points: np.ndarray, quantile: float = ROBUST_QUANTILE) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(low [3], high [3])``: per-axis quantiles of the points (min/max for fewer than 200 points)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        return np.full(3, -1.0), np.full(3, 1.0)
    if len(pts) < 200:
        return pts.min(axis=0), pts.max(axis=0)
    return np.quantile(pts, quantile, axis=0), np.quantile(pts, 1.0 - quantile, axis=0)


# ------------------------------------------------------------------------------------------------------ geometry
def ellipsoid_mesh(means: np.ndarray, rotations: np.ndarray, scales: np.ndarray, *, sigmas: float = ELLIPSOID_SIGMAS,
                   subdivisions: int = 1) -> "pv.PolyData":
    """Return one triangle mesh holding the ellipsoid of every Gaussian, with a ``gaussian`` index per point.

    Each ellipsoid is an icosphere (42 points at ``subdivisions=1``) mapped by ``x -> mean + R diag(sigmas * s) x``;
    normals are ``R diag(1 / s) x`` normalised, the inverse transpose, so flat Gaussians light as discs.

    Args:
        means: ``[N, 3]`` centres.
        rotations: ``[N, 3, 3]`` rotation matrices (``GaussianCloud.rotations()``).
        scales: ``[N, 3]`` standard deviations (``GaussianCloud.scales``).
        sigmas: the surface drawn, in standard deviations.
        subdivisions: icosphere subdivisions (0: 12 points, 1: 42, 2: 162).
    """
    means = np.asarray(means, dtype=np.float64)
    n = len(means)
    if means.shape != (n, 3) or np.shape(rotations) != (n, 3, 3) or np.shape(scales) != (n, 3):
        raise ConfigError(f"ellipsoid_mesh needs means [N, 3], rotations [N, 3, 3], scales [N, 3]; got "
                          f"{means.shape}, {np.shape(rotations)}, {np.shape(scales)}")
    sphere = pv.Icosphere(radius=1.0, nsub=subdivisions)
    unit = np.asarray(sphere.points, dtype=np.float64)
    tri = np.asarray(sphere.faces, dtype=np.int64).reshape(-1, 4)[:, 1:]
    v = len(unit)
    s = np.asarray(scales, dtype=np.float64)
    rot = np.asarray(rotations, dtype=np.float64)
    points = means[:, None, :] + np.einsum("nij,nj,vj->nvi", rot, sigmas * s, unit)
    # a zero scale axis (flat Gaussian) has a normal along it: clamp 1/s instead of dividing by zero
    inv = 1.0 / np.maximum(s, 1e-12 * np.maximum(s.max(axis=1, keepdims=True), 1e-30))
    normals = np.einsum("nij,nj,vj->nvi", rot, inv, unit)
    normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-30)
    faces = tri[None, :, :] + (np.arange(n, dtype=np.int64) * v)[:, None, None]
    cells = np.concatenate([np.full((n * len(tri), 1), 3, dtype=np.int64), faces.reshape(-1, 3)], axis=1)
    mesh = pv.PolyData(points.reshape(-1, 3).astype(np.float32), cells.ravel())
    mesh.point_data["Normals"] = normals.reshape(-1, 3).astype(np.float32)
    mesh.point_data.active_normals_name = "Normals"
    mesh.point_data["gaussian"] = np.repeat(np.arange(n, dtype=np.int64), v)
    return mesh


def _per_point(mesh: "pv.PolyData", values: np.ndarray, is_ellipsoids: bool) -> np.ndarray:
    """Return per-Gaussian ``values`` spread to the mesh's points (one row per Gaussian for splats)."""
    return values[mesh.point_data["gaussian"]] if is_ellipsoids else values


# ------------------------------------------------------------------------------------------------------ camera
def robust_sphere(points: np.ndarray, quantile: float = ROBUST_QUANTILE) -> tuple[np.ndarray, float]:
    """Return ``(centre [3], radius)`` of a sphere holding all but a ``quantile`` share of the points.

    The centre is the middle of the per-axis quantile box, the radius the ``1 - quantile`` quantile of the distances
    to it, so a few stray Gaussians neither move nor inflate the framed object.
    """
    low, high = robust_bounds(points, quantile)
    centre = 0.5 * (low + high)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        return centre, 1.0
    dist = np.linalg.norm(pts - centre, axis=1)
    radius = float(dist.max() if len(pts) < 200 else np.quantile(dist, 1.0 - quantile))
    return centre, max(radius, 1e-6)


def frame_camera(plotter: "pv.Plotter", centre: Sequence[float], radius: float, camera: str = "iso",
                 margin: float = 1.1, up: Sequence[float] | None = None) -> float:
    """Return the camera distance after pointing ``plotter`` at the sphere ``(centre, radius)`` from ``camera``.

    The sphere fits the narrower of the two view angles, times ``margin``. Directions are those of
    :data:`CAMERAS`: ``+x`` puts the camera on the +x side looking back; ``xy`` is the xy plane seen from +z.
    Without ``up`` the view up is +z (+y for views along z) and ``iso`` looks from +x+y+z; with the cloud's ``up``
    (:mod:`roodi_toolkit.render.upright`) the view stands on it (another axis when looking along it) and ``iso``
    looks diagonally from above on it.
    """
    _check_choice(camera, CAMERAS, "camera")
    centre = np.asarray(centre, dtype=np.float64)
    radius = max(float(radius), 1e-6)
    direction, view_up = (np.asarray(v, dtype=np.float64) for v in _DIRECTIONS[camera])
    if up is not None:
        up_v, e1, e2 = horizontal_basis(up)
        if camera == "iso":
            direction = e1 + e2 + up_v
        view_up = up_v
        if abs(float(view_up @ direction) / np.linalg.norm(direction)) > 0.99:  # looking along the up
            view_up = e2
    up = view_up
    direction /= np.linalg.norm(direction)
    width, height = plotter.window_size
    vfov = math.radians(VIEW_ANGLE_DEG)
    hfov = 2.0 * math.atan(math.tan(vfov / 2.0) * width / max(height, 1))
    distance = margin * radius / math.sin(min(vfov, hfov) / 2.0)
    plotter.camera.view_angle = VIEW_ANGLE_DEG
    plotter.camera_position = [tuple(centre + distance * direction), tuple(centre), tuple(up)]
    plotter.renderer.ResetCameraClippingRange()
    return distance


def project_points(plotter: "pv.Plotter", points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(pixels [N, 2], in_front [N])``: (column, row from the top) of world points in the plotter's image.

    Example (tests use it to find where a Gaussian lands in a screenshot):
        >>> import pyvista as pv
        >>> pl = pv.Plotter(off_screen=True, window_size=(200, 100))
        >>> _ = frame_camera(pl, [0, 0, 0], 1.0, "+z")
        >>> px, ok = project_points(pl, np.zeros((1, 3)))
        >>> px.round(1).tolist(), ok.tolist()
        ([[100.0, 50.0]], [True])
        >>> pl.close()
    """
    width, height = plotter.window_size
    cam = plotter.renderer.GetActiveCamera()
    m = cam.GetCompositeProjectionTransformMatrix(width / height, -1.0, 1.0)
    mat = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    clip = np.concatenate([pts, np.ones((len(pts), 1))], axis=1) @ mat.T
    w = clip[:, 3]
    safe = np.where(np.abs(w) > 1e-30, w, 1e-30)
    ndc = clip[:, :2] / safe[:, None]
    col = (ndc[:, 0] + 1.0) * 0.5 * width
    row = (1.0 - (ndc[:, 1] + 1.0) * 0.5) * height
    return np.stack([col, row], axis=1), w > 0


# ------------------------------------------------------------------------------------------------------ plotting
def _colors_rgba(cloud: GaussianCloud) -> np.ndarray:
    """Return ``[N, 4]`` uint8: SH DC colour clipped to [0, 1], opacity as alpha."""
    rgba = np.concatenate([np.clip(cloud.rgb, 0.0, 1.0), cloud.opacities[:, None]], axis=1)
    return (rgba * 255.0 + 0.5).astype(np.uint8)


def _scalar(cloud: GaussianCloud, color_by: str, distances: np.ndarray | None,
            distance_log: bool = True) -> tuple[np.ndarray, str, bool]:
    """Return per-Gaussian scalars, the colour bar title and whether the bar is logarithmic."""
    if color_by == "opacity":
        return cloud.opacities.astype(np.float64), "opacity", False
    if color_by == "scale":
        return cloud.scales.max(axis=1).astype(np.float64), "largest scale", True
    if distances is None:
        raise ConfigError("color_by='distance' needs the per-Gaussian mean distances (distances=...; "
                          "distances_per_gaussian(report) gives them)")
    d = np.asarray(distances, dtype=np.float64)
    if d.shape != (len(cloud),):
        raise ConfigError(f"distances must be [N] = [{len(cloud)}], got {d.shape}")
    if not distance_log:  # the local tests' blob score: a log ratio already, negative for most Gaussians
        return d, "blob score", False
    # log colour scale: d = 0 (duplicate centres) has no logarithm, show it as "no value"
    return np.where(d > 0, d, np.nan), "mean distance to neighbours", True


def _checked_keep(cloud: GaussianCloud, keep_mask: np.ndarray | None, highlight: Any,
                  window_size: Sequence[int]) -> tuple[np.ndarray, tuple[int, ...]]:
    """Return the keep mask ``[N]`` bool (all True for None) and the window size, both checked.

    Raises:
        ConfigError: a mask of the wrong shape or type, a highlight that is no colour, a window size that is no
            ``(width, height)``.
    """
    n = len(cloud)
    keep = np.ones(n, dtype=bool) if keep_mask is None else np.asarray(keep_mask)
    if keep.shape != (n,) or keep.dtype != np.bool_:
        raise ConfigError(f"keep_mask must be a bool array [N] = [{n}], got {keep.dtype} {keep.shape}")
    if highlight is not None:
        try:
            pv.Color(highlight)
        except ValueError:
            raise ConfigError(f"highlight is not a colour: {highlight!r} (use a name such as 'red' or "
                              "'#ff00ff', or None)") from None
    size = tuple(int(v) for v in window_size)
    if len(size) != 2 or min(size) < 1:
        raise ConfigError(f"window_size must be (width, height) in pixels, got {window_size}")
    return keep, size


def _frame_kept(plotter: "pv.Plotter", cloud: GaussianCloud, keep: np.ndarray, finite: np.ndarray, camera: str,
                up: Sequence[float] | None) -> None:
    """Aim the camera at a robust sphere round the kept Gaussians (all of them when none is kept), at least as large
    as their footprint so that a tiny or single-Gaussian object is framed too."""
    frame_idx = np.flatnonzero(keep & finite)
    if frame_idx.size == 0:
        frame_idx = np.flatnonzero(finite)
    centre, radius = robust_sphere(cloud.means[frame_idx])
    radius = max(radius, 3.0 * float(np.median(cloud.scales[frame_idx].max(axis=1))))
    frame_camera(plotter, centre, radius, camera, up=up)


@dataclass
class _ColourMap:
    """A quantity drawn through a colour map: its per-Gaussian values ``[N]``, the bar's title, log scale and
    range (over the Gaussians not highlighted, None when none is finite)."""

    scalars: np.ndarray
    title: str
    log: bool
    clim: list[float] | None


def _colour_map(cloud: GaussianCloud, color_by: str, distances: np.ndarray | None, distance_log: bool,
                distance_label: str | None, groups: list[tuple[np.ndarray, bool]]) -> _ColourMap | None:
    """Return the colour map of ``color_by`` over the drawn ``groups`` (index arrays, highlighted or not); None for
    ``rgb``, the Gaussians' own colours."""
    if color_by == "rgb":
        return None
    scalars, title, log_bar = _scalar(cloud, color_by, distances, distance_log)
    if color_by == "distance" and distance_label:
        title = distance_label
    clim = None
    drawn = np.concatenate([idx for idx, lit in groups if not lit])
    values = scalars[drawn]
    values = values[np.isfinite(values)]
    if values.size:
        clim = [float(values.min()), float(values.max())]
        if clim[0] == clim[1]:
            clim[1] = clim[0] * 1.01 + 1e-12
    return _ColourMap(scalars, title, log_bar, clim)


def _glyph_mesh(sub: GaussianCloud, use_ellipsoids: bool, sigmas: float) -> "pv.PolyData":
    """Return the Gaussians' glyphs: ellipsoid surfaces, or their centres with the splat sizes as ``footprint``."""
    if use_ellipsoids:
        return ellipsoid_mesh(sub.means, sub.rotations(), sub.scales, sigmas=sigmas)
    mesh = pv.PolyData(np.ascontiguousarray(sub.means, dtype=np.float32))
    mesh.point_data["gaussian"] = np.arange(len(sub), dtype=np.int64)
    mesh.point_data["footprint"] = footprint_scales(sub)
    return mesh


def _colour_glyphs(mesh: "pv.PolyData", sub: GaussianCloud, idx: np.ndarray, is_highlight: bool, highlight: Any,
                   colours: _ColourMap | None, use_ellipsoids: bool) -> dict[str, Any]:
    """Colour the glyphs of the Gaussians ``idx`` (``sub``) and return the ``add_mesh`` arguments that draw them:
    highlighted, through the colour map, or in their own colours."""
    kwargs: dict[str, Any] = {}
    if is_highlight:
        # the footprint, unlit in the highlight colour without hiding what it covers: ellipsoids as wireframes,
        # splats with the Gaussian's own opacity (how much it shows in a render)
        if use_ellipsoids:
            kwargs.update(color=highlight, lighting=False, style="wireframe",
                          opacity=HIGHLIGHT_WIREFRAME_OPACITY, line_width=1.0)
        else:
            alpha = sub.opacities.astype(np.float32)
            colour = np.asarray(pv.Color(highlight).int_rgb, dtype=np.uint8)
            mesh.point_data["rgba"] = np.concatenate(
                [np.broadcast_to(colour, (len(idx), 3)), (alpha[:, None] * 255 + 0.5).astype(np.uint8)], axis=1)
            kwargs.update(scalars="rgba", rgb=True, lighting=False)
    elif colours is not None:
        mesh.point_data[colours.title] = _per_point(mesh, colours.scalars[idx], use_ellipsoids)
        kwargs.update(scalars=colours.title, cmap="viridis", clim=colours.clim, log_scale=colours.log,
                      nan_color="grey", opacity=1.0,
                      scalar_bar_args={"title": colours.title, "fmt": "%.3g", "color": "white"})
    else:
        mesh.point_data["rgba"] = _per_point(mesh, _colors_rgba(sub), use_ellipsoids)
        kwargs.update(scalars="rgba", rgb=True)
    return kwargs


def _add_group(plotter: "pv.Plotter", cloud: GaussianCloud, idx: np.ndarray, is_highlight: bool, highlight: Any,
               colours: _ColourMap | None, use_ellipsoids: bool, sigmas: float) -> None:
    """Draw the Gaussians ``idx`` as ellipsoids or splats; highlighted ones also get an opaque marker at their
    centres."""
    sub = cloud.select(idx)
    mesh = _glyph_mesh(sub, use_ellipsoids, sigmas)
    kwargs = _colour_glyphs(mesh, sub, idx, is_highlight, highlight, colours, use_ellipsoids)
    if use_ellipsoids:
        if not is_highlight:
            kwargs.update(smooth_shading=True, ambient=0.35, diffuse=0.65, specular=0.0)
        plotter.add_mesh(mesh, reset_camera=False, **kwargs)
    else:
        actor = plotter.add_mesh(mesh, style="points_gaussian", emissive=False, reset_camera=False,
                                 render_points_as_spheres=False, **kwargs)
        actor.mapper.scale_array = "footprint"
        if is_highlight or colours is None:
            # splats ignore the colour's alpha channel: per-Gaussian opacity goes through the mapper
            mesh.point_data["alpha"] = sub.opacities.astype(np.float32)
            actor.mapper.SetOpacityArray("alpha")
    if is_highlight:
        # an opaque, unlit square at every removed centre: exactly the highlight colour, seen at any size
        plotter.add_points(np.ascontiguousarray(sub.means, dtype=np.float32), color=highlight,
                           point_size=HIGHLIGHT_MARKER_PIXELS, render_points_as_spheres=False, lighting=False,
                           reset_camera=False)


def plot_cloud(cloud: GaussianCloud, keep_mask: np.ndarray | None = None, *, show: str = InspectView.show,
               color_by: str = InspectView.color_by, distances: np.ndarray | None = None,
               highlight: Any = InspectView.highlight, glyphs: str = InspectView.glyphs,
               camera: str = InspectView.camera, off_screen: bool | None = None,
               window_size: Sequence[int] = DEFAULT_WINDOW_SIZE, background: Any = DEFAULT_BACKGROUND,
               sigmas: float = ELLIPSOID_SIGMAS, distance_label: str | None = None,
               distance_log: bool = True, up: Sequence[float] | None = None) -> "pv.Plotter":
    """Return a configured ``pyvista.Plotter`` showing the cloud, the Gaussians pruning removes highlighted.

    Call ``.show()`` for a window, or ``.screenshot(None, return_img=True)`` off screen.

    Args:
        cloud: the Gaussians.
        keep_mask: ``[N]`` bool, False for the removed (``PruneResult.keep_mask``); None keeps everything.
        show: ``both``, ``kept`` or ``removed``.
        color_by: ``rgb`` (own colour, opacity as alpha), ``opacity``, ``scale`` (largest axis, log colour bar) or
            ``distance`` (mean neighbour distance, log colour bar; needs ``distances``). Colour-mapped Gaussians
            are drawn opaque so that faint ones stay visible.
        distances: ``[N]`` mean neighbour distances (:func:`distances_per_gaussian`), NaN where not evaluated.
        highlight: colour of the removed Gaussians (any PyVista colour); None colours them like the kept ones.
        glyphs: ``auto`` (ellipsoids up to :data:`ELLIPSOID_MAX_GAUSSIANS` drawn Gaussians, splats above),
            ``ellipsoids`` or ``splats``.
        camera: view direction, one of :data:`CAMERAS`; the camera frames a robust bounding sphere of the kept
            Gaussians (:func:`robust_sphere`).
        off_screen: render without a window; None: off screen when no display is available.
        window_size: ``(width, height)`` in pixels.
        background: background colour.
        sigmas: standard deviations at which ellipsoids are drawn.
        distance_label: colour bar title for ``color_by='distance'`` (e.g. "mean W2^2 to 16 neighbours").
        distance_log: a logarithmic colour bar for ``distances`` (False for the local tests' blob scores,
            :func:`distance_is_log`).
        up: the cloud's up (:func:`frame_camera`); None: z.

    Raises:
        ConfigError: an unknown option, a mask or distances of the wrong shape, or nothing to draw.
    """
    _check_choice(show, SHOW, "show")
    _check_choice(color_by, COLOR_BY, "color_by")
    _check_choice(glyphs, GLYPHS, "glyphs")
    _check_choice(camera, CAMERAS, "camera")
    keep, size = _checked_keep(cloud, keep_mask, highlight, window_size)
    finite = ~cloud.nonfinite_rows()
    kept_idx = np.flatnonzero(keep & finite) if show in ("both", "kept") else np.zeros(0, dtype=np.int64)
    removed_idx = np.flatnonzero(~keep & finite) if show in ("both", "removed") else np.zeros(0, dtype=np.int64)
    if kept_idx.size + removed_idx.size == 0:
        raise ConfigError(f"nothing to show: no {'removed' if show == 'removed' else 'kept'} Gaussians "
                          "(with finite values)")
    use_ellipsoids = glyphs == "ellipsoids" or (
        glyphs == "auto" and kept_idx.size + removed_idx.size <= ELLIPSOID_MAX_GAUSSIANS)

    _quiet_vtk()
    if off_screen is None:
        off_screen = bool(pv.OFF_SCREEN) or not display_available()
    plotter = pv.Plotter(off_screen=off_screen, window_size=list(size))
    plotter.set_background(background)
    # frame the object (the kept Gaussians); actors are added with reset_camera=False so the framing stays
    _frame_kept(plotter, cloud, keep, finite, camera, up)

    groups = [(kept_idx, False), (removed_idx, highlight is not None)]
    if highlight is None:  # removed drawn like the kept: one actor
        groups = [(np.union1d(kept_idx, removed_idx), False)]
    colours = _colour_map(cloud, color_by, distances, distance_log, distance_label, groups)
    for idx, is_highlight in groups:
        if idx.size:
            _add_group(plotter, cloud, idx, is_highlight, highlight, colours, use_ellipsoids, sigmas)
    plotter.renderer.ResetCameraClippingRange()
    return plotter


# ------------------------------------------------------------------------------------------------------ outputs
def screenshot_image(plotter: "pv.Plotter") -> np.ndarray:
    """Return the plotter's current image ``[H, W, 3]`` uint8, rendering it off screen if needed."""
    img = plotter.screenshot(None, return_img=True)
    return np.asarray(img)[..., :3].copy()
