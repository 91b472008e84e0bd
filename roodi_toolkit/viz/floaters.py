"""The floater picture: what a prune removes, seen at a glance (``prune --dry-run`` and ``inspect --screenshot``).

One PNG, laid out in pixels (:data:`PANEL`):

- a title with the counts (what goes of what was judged) and the mode;
- three views of the cloud standing on its own up (:mod:`roodi_toolkit.render.upright`): from the front, from the
  side and from above. What stays is drawn in grey, as the density of its centres (an X-ray: dense surfaces dark,
  sparse ones light); what goes is drawn over it as markers large enough to be seen whatever the Gaussian's size, in
  one strong colour per reason (:data:`REASON_COLOURS`). Floaters beyond the frame (which holds what stays) are
  drawn as arrows at its border, and their number is written in the panel;
- the cloud rendered before and after the prune from the first view, side by side (the built-in renderer unless
  another is given);
- a legend: the count per reason, the Gaussians a test flagged that stay and why, the mode and where the up came from.

The views project centres with the same :class:`~roodi_toolkit.cameras.Camera` the renders use, so a marker sits
where its Gaussian renders. Nothing is written here: :func:`floater_picture` returns the image and the layout, the
commands write it (:func:`roodi_toolkit.io.files.write_image`).
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from ..cameras import Camera
from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..params import GaussianParams
from ..progress import ProgressFactory, null_progress
from ..prune.summary import STAGE_LABELS, mode_line
from ..render.renderer import resolve_renderer
from ..render.views import framing_orbit

if TYPE_CHECKING:  # pragma: no cover
    from ..prune.outliers import PruneReport
    from ..render.upright import UpAxis

PANEL = (560, 420)
"""Width and height in pixels of each of the six panels."""
GAP = 20
TITLE_BAND = 84
LABEL_BAND = 30
DPI = 100
REASON_COLOURS = {
    "detached": "#e41a1c",     # red
    "oversized": "#1a56ff",    # blue
    "fog": "#00b140",          # green
    "statistical": "#e41a1c",  # red: the statistical rule's only reason
}
"""Marker colour per stage; the filters (NaN/Inf, opacity, box, sphere, value ranges) are orange."""
FILTER_COLOUR = "#ff8c00"
KEPT_BACKGROUND = 1.0
"""The views' background (white); what stays is grey on it."""
RENDER_BACKGROUND = (0.0, 0.0, 0.0)
"""The before/after renders' background (black, as ``roodi-toolkit render``)."""
VIEW_NAMES = ("side view", "turned 90 degrees", "from above")


@dataclass
class FloaterPicture:
    """The picture and how it is laid out.

    Attributes:
        image: ``[H, W, 3]`` uint8.
        cameras: the views' cameras by panel name (``front``, ``side``, ``above``, ``before``, ``after``).
        panels: ``(x0, y0)`` of each panel's top-left pixel in ``image`` (a camera pixel ``(u, v)`` lands at
            ``(x0 + u, y0 + v)``).
        colours: the marker colour of each stage that removed Gaussians, as ``[3]`` uint8.
        beyond: Gaussians that go but lie outside each view's frame (drawn as arrows at its border).
    """

    image: np.ndarray = field(repr=False)
    cameras: dict[str, Camera] = field(repr=False)
    panels: dict[str, tuple[int, int]]
    colours: dict[str, np.ndarray] = field(repr=False)
    beyond: dict[str, int] = field(default_factory=dict)


def reason_colour(stage: str) -> str:
    """Return the marker colour (hex) of a stage's removals."""
    return REASON_COLOURS.get(stage, FILTER_COLOUR)


def picture_views(cloud: GaussianCloud, keep: np.ndarray, up: Sequence[float],
                  size: tuple[int, int] = PANEL) -> dict[str, Camera]:
    """Return the picture's three views (``front``, ``side``, ``above``), framed on what stays and standing on ``up``.

    The front and side views are 90 degrees apart at 20 degrees elevation, the view from above at 80 degrees (not
    90: the image's up then stays defined), all at the distance of :func:`~roodi_toolkit.render.views.framing_orbit`
    (what stays fills the narrower field of view; raised while a view starts inside it).
    """
    frame = cloud.select(keep) if keep.any() else cloud
    w, h = size
    side = framing_orbit(frame, 4, elevation_deg=20.0, width=w, height=h, up=up, azimuth0_deg=-60.0)
    above = framing_orbit(frame, 1, elevation_deg=80.0, width=w, height=h, up=up, azimuth0_deg=-60.0)
    return {"front": side[0], "side": side[1], "above": above[0]}


def density_view(points: np.ndarray, weights: np.ndarray, camera: Camera) -> np.ndarray:
    """Return ``[H, W]`` float grey levels in [0, 1] (1 = background) of the ``points`` ``[N, 3]`` seen by ``camera``:
    the ``weights`` ``[N]`` (opacities) summed per pixel, on a log scale, darkest at the 99.5th percentile."""
    w, h = camera.width, camera.height
    px, z = camera.project(points)
    ok = (z > camera.near) & np.isfinite(px).all(axis=1)
    col, row = np.floor(px[ok, 0]).astype(np.int64), np.floor(px[ok, 1]).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    acc = np.bincount(row[inside] * w + col[inside], weights=np.asarray(weights, np.float64)[ok][inside],
                      minlength=w * h).reshape(h, w)
    if not (acc > 0).any():
        return np.full((h, w), KEPT_BACKGROUND)
    level = np.log1p(acc / max(float(np.quantile(acc[acc > 0], 0.5)), 1e-12))
    top = max(float(np.quantile(level[acc > 0], 0.995)), 1e-12)
    return KEPT_BACKGROUND - 0.8 * np.clip(level / top, 0.0, 1.0)


def _marker_size(count: int) -> float:
    """Marker area in points^2: large for a few floaters, smaller when thousands would cover the view."""
    return 42.0 if count <= 500 else 22.0 if count <= 5000 else 9.0


def _removal_groups(keep: np.ndarray, report: "PruneReport", n: int) -> tuple[np.ndarray, list[tuple[str, int]]]:
    """Return each Gaussian's removing stage ``[N]`` (an index into the stages, -1 where it stays) and the stages'
    (name, count); a report without per-Gaussian stages makes what goes one group, ``removed``.

    Raises:
        ConfigError: a keep mask that is not ``[N]`` bool.
    """
    if keep.shape != (n,) or keep.dtype != np.bool_:
        raise ConfigError(f"keep must be a bool array [N] = [{n}], got {keep.dtype} {keep.shape}")
    removed_by = np.asarray(report.removed_by)
    stage_counts = list(report.stages)
    if removed_by.shape != (n,):
        removed_by = np.where(keep, -1, 0).astype(np.int16)
        stage_counts = [("removed", int((~keep).sum()))]
    return removed_by, stage_counts


class _Sheet:
    """The picture's matplotlib figure: two rows of three panels of ``pw`` x ``ph`` pixels under a title band, each
    panel's axes in pixel units (y down, as camera pixels) and a label above it."""

    def __init__(self, pw: int, ph: int) -> None:
        self.pw, self.ph = pw, ph
        self.width = 3 * pw + 4 * GAP
        self.height = TITLE_BAND + 2 * (LABEL_BAND + ph) + 3 * GAP // 2
        self.fig = Figure(figsize=(self.width / DPI, self.height / DPI), dpi=DPI, facecolor="white")
        FigureCanvasAgg(self.fig)
        self.panels: dict[str, tuple[int, int]] = {}

    def axes(self, name: str, col: int, row: int, label: str) -> Any:
        """Return the axes of the panel at ``col``, ``row`` labelled ``label`` (its label text as ``_roodi_label``)."""
        pw, ph, width, height = self.pw, self.ph, self.width, self.height
        x0 = GAP + col * (pw + GAP)
        y0 = TITLE_BAND + row * (LABEL_BAND + ph + GAP // 2) + LABEL_BAND
        self.panels[name] = (x0, y0)
        ax = self.fig.add_axes((x0 / width, 1.0 - (y0 + ph) / height, pw / width, ph / height))
        ax.set_xlim(0, pw)
        ax.set_ylim(ph, 0)
        ax.set_axis_off()
        ax._roodi_label = self.fig.text(x0 / width, 1.0 - (y0 - 6) / height, label, fontsize=13, ha="left",
                                        va="bottom")
        return ax

    def text(self, y: float, text: str, **kwargs: Any) -> None:
        """Write ``text`` across the top band, its top ``y`` pixels down."""
        self.fig.text(GAP / self.width, 1.0 - y / self.height, text, ha="left", va="top", **kwargs)

    def image(self) -> np.ndarray:
        """Return the drawn picture ``[H, W, 3]`` uint8."""
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()


def _draw_view(ax: Any, cam: Camera, shown: GaussianCloud, keep: np.ndarray, removed_by: np.ndarray,
               stages: list[tuple[int, str, int]], colours: dict[str, str]) -> int:
    """Draw one view: what stays as a grey density, what goes as markers in its stage's colour (arrows at the
    border for what lies beyond the frame); return how many lie beyond it."""
    pw, ph = cam.width, cam.height
    grey = density_view(shown.means[keep], shown.opacities[keep], cam)
    ax.imshow(np.repeat(grey[..., None], 3, axis=2), extent=(0, pw, ph, 0), interpolation="nearest")
    outside = 0
    for index, stage, count in stages:
        sel = removed_by == index
        px, z = cam.project(shown.means[sel])
        front = z > cam.near
        px = px[front]
        inner = (px[:, 0] >= 0) & (px[:, 0] < pw) & (px[:, 1] >= 0) & (px[:, 1] < ph)
        size = _marker_size(count)
        ax.scatter(px[inner, 0], px[inner, 1], s=size, c=colours[stage], edgecolors="black", linewidths=0.6,
                   zorder=3)
        out = px[~inner]
        outside += int((~inner).sum() + (~front).sum())
        if len(out):
            _border_arrows(ax, out, colours[stage], pw, ph)
    return outside


def _render_before_after(shown: GaussianCloud, keep: np.ndarray, camera: Camera, renderer: Any,
                         progress: ProgressFactory) -> list[np.ndarray]:
    """Return the cloud rendered from ``camera`` before and after the prune, ``[H, W, 3]`` in [0, 1] each (black
    where nothing is left)."""
    renderer = resolve_renderer(renderer)
    with progress(total=2, desc="rendering before and after") as bar:
        renders = []
        for part in (shown, shown.select(keep)):
            if len(part):
                with torch.no_grad():
                    out = renderer.render(GaussianParams.from_cloud(part), camera, background=RENDER_BACKGROUND)
                renders.append(np.clip(out.rgb.detach().cpu().numpy(), 0.0, 1.0))
            else:
                renders.append(np.zeros((camera.height, camera.width, 3)))
            bar.update(1)
    return renders


def floater_picture(cloud: GaussianCloud, keep: np.ndarray, report: "PruneReport", up: "UpAxis | Sequence[float]",
                    *, title: str = "", renderer: Any = None, progress: ProgressFactory = null_progress,
                    dry_run: bool = False, panel: tuple[int, int] = PANEL) -> FloaterPicture:
    """Return the floater picture of a prune (module docstring).

    Args:
        cloud: the cloud that was pruned (all of it).
        keep: ``[N]`` bool, the prune's keep mask.
        report: the prune's report (its ``removed_by`` colours the markers, its counts fill the legend).
        up: an :class:`~roodi_toolkit.render.upright.UpAxis` (its source is written in the legend) or a vector.
        title: what the picture is of (e.g. the file name).
        renderer: renders the before/after panels (an instance, a registered name, or None: the built-in one).
        progress: progress factory (the two renders take most of the time).
        dry_run: word the counts as what would go.
        panel: width and height of each panel in pixels.

    Raises:
        ConfigError: a keep mask or report that does not match the cloud.
    """
    n = len(cloud)
    keep = np.asarray(keep)
    removed_by, stage_counts = _removal_groups(keep, report, n)
    vector = np.asarray(getattr(up, "vector", up), dtype=np.float64)
    up_source = getattr(up, "source", "given")
    finite = ~cloud.nonfinite_rows()
    shown = cloud.select(finite) if not finite.all() else cloud
    keep_f, by_f = keep[finite], removed_by[finite]
    pw, ph = (int(v) for v in panel)
    if pw < 64 or ph < 64:
        raise ConfigError(f"panels must be at least 64x64 pixels, got {pw}x{ph}")
    views = picture_views(shown, keep_f, vector, (pw, ph))
    sheet = _Sheet(pw, ph)

    stages = [(i, name, count) for i, (name, count) in enumerate(stage_counts) if count]
    colours = {name: reason_colour(name) for _, name, _ in stages}
    beyond: dict[str, int] = {}
    for col, (name, label) in enumerate(zip(("front", "side", "above"), VIEW_NAMES)):
        ax = sheet.axes(name, col, 0, f"{label}: what stays in grey, what goes in colour")
        beyond[name] = outside = _draw_view(ax, views[name], shown, keep_f, by_f, stages, colours)
        if outside:  # said above the panel, where no marker can hide under it
            ax._roodi_label.set_text(f"{label}: {outside:,} going beyond the frame (arrows)")
        ax.add_patch(_frame(pw, ph))

    front = views["front"]
    renders = _render_before_after(shown, keep_f, front, renderer, progress)
    went, kept = n - int(keep.sum()), int(keep.sum())
    for col, (name, label, img) in enumerate((("before", f"before: all {n:,} Gaussians", renders[0]),
                                               ("after", f"after: the {kept:,} that stay", renders[1]))):
        ax = sheet.axes(name, col, 1, label + " (rendered, side view)")
        ax.imshow(img, extent=(0, pw, ph, 0), interpolation="nearest")

    ax = sheet.axes("legend", 2, 1, "what goes, by reason")
    _legend(ax, report, stages, colours, kept, went, up_source, vector, pw, ph, dry_run)

    verb = "would go" if dry_run else "go"
    share = went / max(n, 1)
    head = f"{went:,} of {n:,} Gaussians {verb} ({share:.2%}), {kept:,} stay" if went else \
        f"nothing {'would go' if dry_run else 'goes'}: all {n:,} Gaussians stay"
    sheet.text(16, f"{title}: {head}" if title else head, fontsize=19, weight="bold")
    sheet.text(52, mode_line(report), fontsize=12, color="#333333")
    image = sheet.image()
    cams = dict(views, before=front, after=front)
    rgb = {name: (np.array([int(c[i:i + 2], 16) for i in (1, 3, 5)], dtype=np.uint8)) for name, c in colours.items()}
    return FloaterPicture(image, cams, sheet.panels, rgb, beyond)


def _frame(pw: int, ph: int) -> Any:
    return Rectangle((0, 0), pw, ph, fill=False, edgecolor="#999999", linewidth=1.0)


def _border_arrows(ax: Any, pixels: np.ndarray, colour: str, pw: int, ph: int) -> None:
    """Draw the floaters beyond the frame as arrowheads at its border, pointing the way they lie."""
    centre = np.array([pw / 2.0, ph / 2.0])
    d = np.nan_to_num(pixels - centre, nan=0.0, posinf=1e9, neginf=-1e9)
    # scale each direction onto the border (6 px inside it)
    scale = np.minimum((pw / 2.0 - 6) / np.maximum(np.abs(d[:, 0]), 1e-9),
                       (ph / 2.0 - 6) / np.maximum(np.abs(d[:, 1]), 1e-9))
    at = centre + d * scale[:, None]
    horizontal = np.abs(d[:, 0]) * ph >= np.abs(d[:, 1]) * pw
    for marker, sel in ((">", horizontal & (d[:, 0] > 0)), ("<", horizontal & (d[:, 0] <= 0)),
                        ("v", ~horizontal & (d[:, 1] > 0)), ("^", ~horizontal & (d[:, 1] <= 0))):
        if sel.any():
            ax.scatter(at[sel, 0], at[sel, 1], s=60, c=colour, marker=marker, edgecolors="black", linewidths=0.6,
                       zorder=4)


def _legend(ax: Any, report: "PruneReport", stages: list[tuple[int, str, int]], colours: dict[str, str], kept: int,
            went: int, up_source: str, up: np.ndarray, pw: int, ph: int, dry_run: bool) -> None:
    """Write the legend panel: one coloured marker and count per reason, what stays and why, the up used."""
    ax.add_patch(_frame(pw, ph))
    y = 24.0

    def line(text: str, *, colour: str | None = None, size: float = 12.5, weight: str = "normal",
             marker: str = "o", indent: float = 16.0) -> None:
        nonlocal y
        x = indent
        if colour is not None:
            ax.scatter([x + 6], [y], s=90, c=colour, marker=marker, edgecolors="black", linewidths=0.6)
            x += 22
        # a character is about 0.58 em wide in the default font; an em is size * DPI / 72 pixels
        wrapped = textwrap.wrap(text, width=int((pw - x - 12) / (0.58 * size * DPI / 72.0))) or [""]
        for part in wrapped:
            ax.text(x, y, part, fontsize=size, weight=weight, va="center", ha="left")
            y += size * 1.75
        y += 3

    line(f"{'would go' if dry_run else 'goes'}: {went:,}", weight="bold")
    for _, stage, count in stages:
        detail = report.details.get(stage, "")
        line(f"{STAGE_LABELS.get(stage, stage)} {count:,}" + (f": {detail}" if detail else ""),
             colour=colours[stage], size=11)
    if not stages:
        line("nothing", size=11)
    line(f"stays: {kept:,}", colour="#b0b0b0", marker="s", weight="bold")
    for stage, count, why in report.stayed:
        if count:
            line(f"{count:,} flagged {STAGE_LABELS.get(stage, stage)}, {why}", size=10.5, indent=38.0)
    y += 4
    vec = ", ".join(f"{v:.2g}" for v in up + 0.0)
    line(f"up ({vec}): {up_source}", size=10, indent=16.0)
    if math.isfinite(report.threshold) and report.mode == "statistical":
        line(f"threshold {report.threshold:.4g}", size=10)
