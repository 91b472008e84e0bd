"""``inspect --html``: a self-contained web page to turn the cloud around, what a prune removes marked.

The page is a Plotly 3D scatter (plotly.js embedded, so it opens offline in any browser, nothing to install): what
stays as points in their own colour (or grey), what goes as larger markers in the floater picture's colour per
reason (:data:`~roodi_toolkit.viz.floaters.REASON_COLOURS`), one legend entry per reason with its count (a click on
an entry hides or shows it). The box holds what stays; Gaussians that go beyond it are drawn on its faces as
crosses. The camera stands on the cloud's up and looks at what stays. Large clouds are thinned
evenly to :data:`MAX_KEPT_POINTS` kept points (the page says so); every Gaussian that goes is drawn.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Sequence

import numpy as np
from PIL import Image

from ..cameras import horizontal_basis
from ..errors import EnvironmentProblemError
from ..gaussians import GaussianCloud
from ..io.files import atomic_path
from ..prune.summary import STAGE_LABELS, mode_line
from .floaters import reason_colour

if TYPE_CHECKING:  # pragma: no cover
    from ..prune.outliers import PruneReport

MAX_KEPT_POINTS = 200_000
"""The page draws at most this many of the kept Gaussians (an even stride), so that it stays a few megabytes."""


def floater_page(cloud: GaussianCloud, keep: np.ndarray, report: "PruneReport", up: Sequence[float], *,
                 title: str = "", grey: bool = False) -> str:
    """Return the HTML text of the page (module docstring).

    Args:
        cloud: the cloud that was pruned.
        keep: ``[N]`` bool, the prune's keep mask.
        report: the prune's report (``removed_by`` and ``stages`` give each removed Gaussian its reason).
        up: ``[3]`` the cloud's up (the page's camera stands on it).
        title: the page's heading.
        grey: draw what stays in grey instead of its own colour.

    Raises:
        EnvironmentProblemError: plotly is not installed.
    """
    try:
        import plotly.graph_objects as go  # lazy: plotly is missing from some installs: named with what to do
    except ImportError as exc:
        raise EnvironmentProblemError(f"the HTML page needs plotly ({exc}); install it with `pip install plotly`") \
            from None
    finite = ~cloud.nonfinite_rows()
    keep = np.asarray(keep, dtype=bool)
    removed_by = np.asarray(report.removed_by)
    if removed_by.shape != keep.shape:
        removed_by = np.where(keep, -1, 0)
    kept = np.flatnonzero(keep & finite)
    stride = max(1, int(np.ceil(len(kept) / MAX_KEPT_POINTS)))
    shown = kept[::stride]
    means = cloud.means.astype(np.float32)
    traces = []
    marker: dict = {"size": 1.6, "color": "rgb(150,150,150)"}
    if not grey and len(shown):
        marker.update(palette_colours(cloud.rgb[shown]))
    name = f"stays: {len(kept):,}" + (f" (one in {stride} drawn)" if stride > 1 else "")
    traces.append(go.Scatter3d(x=means[shown, 0], y=means[shown, 1], z=means[shown, 2], mode="markers", name=name,
                               marker=marker, hoverinfo="skip"))
    # the box holds what stays (its 0.5%-99.5% quantiles, 10% margin); floaters beyond it are drawn on its faces
    basis = means[kept] if len(kept) else means[finite]
    low, high = np.quantile(basis, 0.005, axis=0), np.quantile(basis, 0.995, axis=0)
    pad = 0.1 * (high - low) + 1e-9
    low, high = low - pad, high + pad
    for index, (stage, count) in enumerate(report.stages):
        sel = np.flatnonzero((removed_by == index) & finite)
        if not count or not sel.size:
            continue
        label = STAGE_LABELS.get(stage, stage)
        pts = means[sel]
        inside = np.all((pts >= low) & (pts <= high), axis=1)
        for part, symbol, suffix in ((inside, "circle", ""), (~inside, "x", ", beyond the box (on its faces)")):
            if part.any():
                at = np.clip(pts[part], low, high)
                traces.append(go.Scatter3d(x=at[:, 0], y=at[:, 1], z=at[:, 2], mode="markers",
                                           name=f"goes, {label}{suffix}: {int(part.sum()):,}", hovertext=label,
                                           marker={"size": 5, "color": reason_colour(stage), "symbol": symbol,
                                                   "line": {"color": "black", "width": 1}}))
    up_v = np.asarray(up, dtype=np.float64)
    up_v = up_v / max(float(np.linalg.norm(up_v)), 1e-30)
    _, e1, e2 = horizontal_basis(up_v)
    eye = 1.6 * (np.cos(np.radians(20)) * (np.cos(np.radians(-60)) * e1 + np.sin(np.radians(-60)) * e2)
                 + np.sin(np.radians(20)) * up_v)
    went = len(keep) - int(keep.sum())
    heading = f"{title}: " if title else ""
    heading += (f"{went:,} of {len(keep):,} Gaussians would go, {int(keep.sum()):,} would stay"
                f"<br><sub>{mode_line(report)}</sub>")
    ranges = {axis: {"range": [float(low[i]), float(high[i])]} for i, axis in enumerate(("xaxis", "yaxis", "zaxis"))}
    size = high - low
    ratio = dict(zip("xyz", map(float, size / size.max())))
    fig = go.Figure(traces)
    fig.update_layout(title={"text": heading}, template="plotly_white", legend={"itemsizing": "constant"},
                      margin={"l": 0, "r": 0, "t": 70, "b": 0},
                      scene={"aspectmode": "manual", "aspectratio": ratio, **ranges,
                             "camera": {"up": dict(zip("xyz", map(float, up_v))),
                                        "eye": dict(zip("xyz", map(float, eye)))}})
    return fig.to_html(include_plotlyjs=True, full_html=True)


def palette_colours(rgb: np.ndarray, colours: int = 256) -> dict:
    """Return plotly marker settings giving each of ``rgb`` ``[N, 3]`` (0-1) the nearest of a ``colours``-entry
    palette (Pillow's median cut): a per-point index and a colour scale, a byte a point where colour strings take
    about sixteen (a 90k-Gaussian page: 8.1 MB with strings)."""
    pixels = (np.clip(rgb, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)[None]  # [1, N, 3]
    quantised = Image.fromarray(pixels, "RGB").quantize(colours, method=Image.Quantize.MEDIANCUT)
    index = np.asarray(quantised, dtype=np.uint8)[0]  # [N]
    palette = np.asarray(quantised.getpalette()[:3 * colours], dtype=np.int64).reshape(-1, 3)
    top = max(int(index.max()), 1)
    used = palette[:top + 1]
    scale = [[i / top, f"rgb({r},{g},{b})"] for i, (r, g, b) in enumerate(used)]
    if top == 0 or len(scale) == 1:
        scale = [[0.0, scale[0][1]], [1.0, scale[0][1]]]
    return {"color": index, "colorscale": scale, "cmin": 0, "cmax": top, "showscale": False}


def write_floater_page(html: str, path: str | os.PathLike) -> None:
    """Write the page atomically."""
    with atomic_path(path, suffix=".html") as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(html)
