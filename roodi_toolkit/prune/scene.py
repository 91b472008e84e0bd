"""Floater removal that is safe on real scenes: detached clusters and oversized blobs, judged locally.

The statistical rules of :mod:`.outliers` compare every Gaussian's neighbour distance with one global threshold.
Real scenes have wide distributions of that distance (log-MAD 1.24 on a real donut against 0.3 on the synthetic
surfaces), so a global cut either sits far above the floaters or cuts into real content. Here each Gaussian is
judged against its own neighbourhood instead, with two tests that need only the K nearest centres (one K-NN
search, as Euclidean statistical outlier removal) and work in any units:

- **detached** (far specks, fog detached from the content): two Gaussians are linked when their centres are closer
  than ``reach`` times the sum of their largest scales (their ``reach``-sigma ellipsoids can touch), along the K
  nearest-centre edges. The connected components of that graph are the pieces of the scene; real content is one
  piece (measured: 99.8-100% of the Gaussians of the real donut and biker), a floater in empty space a piece of its
  own. Scene mode removes pieces holding less than ``min_cluster`` of the Gaussians; object mode keeps only the
  largest piece. Without photos to judge them, only pieces of at most ``max_piece`` (3) Gaussians go: a far speck
  is alone, while larger detached pieces are mostly real content the linking split off (the real donut's pieces of
  6-56 Gaussians inside its ring: without the limit its pruned renders score 43.7 dB against the unpruned cloud's,
  57.4 dB with it; a cropped capture's chunks of its surroundings, 73-379 Gaussians).
- **oversized** (blobs sitting on the surface): a Gaussian whose *smallest* axis is larger than its neighbours'
  spacing and than its neighbours' typical size is a volume of colour poured over the surface. Real large Gaussians
  are flat (smallest axis far below the spacing) or live among equally large ones. Score, in log units:
  ``(log s_min - log mean neighbour distance) + (log s_min - median over neighbours of log size)``, size being the
  geometric mean of the three scales; a candidate above ``blob_score``. Without photos to judge it, a candidate
  goes only when none of its neighbours has its base colour (the nearest of their SH-DC colours is more than
  ``blob_colour`` away in RGB) or when its score is above ``blob_sure``: a blob of foreign colour occludes the
  surface, while a large Gaussian the colour of a neighbour is most often the optimiser covering an even patch
  with few Gaussians. Measured on six real splats in four formats: the real candidates' nearest neighbour colour
  is 0.03-0.11 away at the median, the planted blobs' 0.10-0.19 at their 5th percentile; ``docs/pruning.md``.
- **foreign blobs** (oversized whatever their score): among large, sparse Gaussians a blob's smallest axis does not
  clear the spacing and it scores low. A Gaussian goes anyway when it is round (:data:`FOREIGN_ROUND`), its
  smallest axis is above ``foreign_size`` times the scene's median size and its neighbours' median size, and none
  of its neighbours has its colour (:data:`FOREIGN_COLOUR`): real Gaussians that large are nearly all flat or share
  a neighbour's colour (0-32 taken per real file, ``docs/pruning.md``).

``docs/pruning.md`` has the measurements behind the constants.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import CloudError
from ..gaussians import GaussianCloud
from ..progress import ProgressFactory, null_progress
from .filters import filtered_report
from .graph import NeighbourGraph, components, neighbour_graph
from .outliers import PruneConfig, PruneResult, remove_statistical_outliers

if TYPE_CHECKING:
    from .outliers import PruneReport
    from .photos import Photos

DETACHED, OVERSIZED, FOG = "detached", "oversized", "fog"
FOREIGN_ROUND = 2.0
"""foreign blobs: the largest axis under this many times the smallest. The planted blobs' axes are jittered by
exp(N(0, 0.2)), so most are under 2; without the limit the test took 58 real donut Gaussians, with it 32
(benchmarks/RESULTS.md, "Round blobs of a foreign colour go whatever their score")."""
FOREIGN_COLOUR = 0.2
"""foreign blobs: the RGB distance (0-1 units) from the Gaussian's base colour to the nearest of its neighbours'
above which no neighbour has its colour (stricter than ``blob_colour``: these have not passed the oversized score)."""
FOG_MIN_FRACTION = 0.05
FOG_MIN_SPREAD = 1.5
FOG_MAX_OPACITY_RATIO = 0.5
"""auto background: a colour's candidates are fog when they are at least 5% of the Gaussians, spread 1.5x wider
from the centre than the rest (median distances) and under half the rest's median opacity. Measured (fraction,
spread, opacity ratio): lego trained on white, white 0.147 / 1.96 / 0.20 (fog); biker black 0.229 / 0.98 / 1.35,
biker white 0.016 / 1.33 / 0.60, donut white 0.013 / 0.99 / 1.52 (real content)."""


def background_fog(cloud: GaussianCloud, background: str, tolerance: float) -> tuple[np.ndarray, str]:
    """Return the fog mask ``[N]`` (Gaussians of the training background's colour) and which background it was.

    Training on a solid white (or black) background leaves diffuse Gaussians of exactly that colour around the
    object: invisible on that background, a halo on any other. A Gaussian is a candidate when every channel of its
    base colour (SH DC) is within ``tolerance`` of white (or black). ``background`` is ``white``, ``black``,
    ``none`` or ``auto`` (each colour whose candidates look like fog, see :data:`FOG_MIN_FRACTION`).
    """
    n = len(cloud)
    if background == "none" or n == 0:
        return np.zeros(n, dtype=bool), "none"
    rgb = cloud.rgb
    candidates = {"white": _axis_extreme(rgb, np.minimum) >= 1.0 - tolerance,
                  "black": _axis_extreme(rgb, np.maximum) <= tolerance}
    if background != "auto":
        return candidates[background], background
    opacity = radius = None  # computed only when a colour gets that far (most real scenes stop before)
    for colour, sel in candidates.items():
        if sel.mean() < FOG_MIN_FRACTION or sel.all():
            continue
        opacity = cloud.opacities if opacity is None else opacity
        if not np.median(opacity[sel]) < FOG_MAX_OPACITY_RATIO * np.median(opacity[~sel]):  # not faint
            continue
        if radius is None:
            means = cloud.means.astype(np.float64)
            radius = np.linalg.norm(means - np.median(means, axis=0), axis=1)
        if np.median(radius[sel]) / max(float(np.median(radius[~sel])), 1e-30) >= FOG_MIN_SPREAD:
            return sel, colour
    return np.zeros(n, dtype=bool), "none"


@dataclass(frozen=True)
class LocalDecision:
    """What the local tests decided for each evaluated Gaussian.

    Attributes:
        detached: ``[M]`` in a piece too small to keep (or, in object mode, not the largest piece).
        oversized: ``[M]`` blob score above the limit (and not already detached).
        component: ``[M]`` piece id of each Gaussian.
        component_sizes: ``[C]`` Gaussians per piece.
        blob_score: ``[M]`` the oversized score.
        largest_fraction: fraction of the Gaussians in the largest piece.
        mode: ``scene`` or ``object``, and ``reason`` why.
        spared: detached pieces kept for holding more than ``max_piece`` Gaussians, and the Gaussians in them.
        colour_spared: oversized candidates kept for having the colour of a neighbour (``blob_colour``).
        foreign: Gaussians found by the foreign-blob test (large, round, of a colour no neighbour has), counted in
            ``oversized``.
        foreign_mask: ``[M]`` which they are (None: none).
    """

    detached: np.ndarray
    oversized: np.ndarray
    component: np.ndarray
    component_sizes: np.ndarray
    blob_score: np.ndarray
    largest_fraction: float
    mode: str
    reason: str
    spared: tuple[int, int] = (0, 0)
    colour_spared: int = 0
    foreign: int = 0
    foreign_mask: np.ndarray | None = None

    @property
    def flagged(self) -> np.ndarray:
        """``[M]`` removed by either test."""
        return self.detached | self.oversized


def _axis_extreme(ls: np.ndarray, pick: Any) -> np.ndarray:
    """Return ``pick`` (np.minimum or np.maximum) over the three columns of ``[N, 3]``: a reduction along rows
    of three is several times slower than two elementwise passes (same values)."""
    return pick(pick(ls[:, 0], ls[:, 1]), ls[:, 2])


def blob_scores(log_min: np.ndarray, log_size: np.ndarray, neighbors: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Return the oversized score ``[N]`` (module docstring): how far the smallest axis exceeds spacing and size.

    ``log_min`` and ``log_size`` ``[N]``: each Gaussian's smallest log scale and mean log scale (log of its size),
    in the order of ``neighbors`` and ``dist`` ``[N, K]``."""
    with np.errstate(over="ignore"):  # centres far out (1e38): an infinite spacing, no overflow warning
        spacing = np.log(np.maximum(dist.mean(axis=1), np.finfo(np.float32).tiny))
    # median of the neighbours' sizes (the lower middle value for even K): robust to a few blobs among them
    mid = (neighbors.shape[1] - 1) // 2
    local = log_size[neighbors]
    local.partition(mid, axis=1)
    return (log_min - spacing) + (log_min - local[:, mid])


def colour_gaps(rgb: np.ndarray, rows: np.ndarray, neighbors: np.ndarray) -> np.ndarray:
    """Return, for each of ``rows``, the RGB distance ``[R]`` from its colour to the nearest colour among its
    neighbours ``neighbors [R, K]`` (indices into ``rgb [N, 3]``; colours clipped to 0-1 first)."""
    own = np.clip(rgb[rows], 0.0, 1.0, dtype=np.float32)
    around = np.clip(rgb[neighbors], 0.0, 1.0, dtype=np.float32)
    return np.sqrt(((around - own[:, None, :]) ** 2).sum(axis=2).min(axis=1, initial=np.inf))


COLOUR_SAMPLE = 65536
"""colours_vary: at most this many Gaussians (evenly strided) are looked at."""


def colours_vary(rgb: np.ndarray, tolerance: float) -> bool:
    """Return whether the cloud has colours to tell apart: a tenth of its Gaussians (of an even sample) lie more than
    ``tolerance`` from its median colour. A one-colour cloud (a grey scan, a mask) gives the colour test of the
    oversized Gaussians nothing to go on: every blob has its neighbours' colour."""
    sample = np.clip(rgb[::max(1, len(rgb) // COLOUR_SAMPLE)], 0.0, 1.0, dtype=np.float32)
    if len(sample) == 0:
        return False
    distance = np.linalg.norm(sample - np.median(sample, axis=0), axis=1)
    return bool(np.quantile(distance, 0.9) > tolerance)


def large_round(ls: np.ndarray, log_min: np.ndarray, log_size: np.ndarray, neighbors: np.ndarray,
                allowed: np.ndarray, foreign_size: float) -> np.ndarray:
    """Return the rows, among ``allowed`` ``[N]``, of the foreign-blob test's shape (module docstring): round, the
    smallest axis above ``foreign_size`` times the scene's median Gaussian size and above the neighbours' median
    size. ``ls [N, 3]`` log scales, their smallest and mean ``log_min``, ``log_size`` ``[N]`` and ``neighbors
    [N, K]`` in one (row) order."""
    large = log_min > np.float32(np.median(log_size) + np.log(foreign_size))
    large &= allowed
    rows = np.flatnonzero(large)
    rows = rows[_axis_extreme(ls[rows], np.maximum) - log_min[rows] < np.log(FOREIGN_ROUND)]
    return rows[log_min[rows] > np.median(log_size[neighbors[rows]], axis=1)]


def decide(log_scales: np.ndarray, graph: NeighbourGraph, config: "PruneConfig",
           max_piece: int | None = None, rgb: np.ndarray | None = None, colour_gate: bool = True) -> LocalDecision:
    """Run the detached and oversized tests (module docstring) on the K-nearest-centre graph of finite Gaussians.

    Args:
        log_scales: ``[N, 3]`` log scales, input order.
        graph: the K nearest centres (:func:`neighbour_graph`).
        config: reach, min_cluster, blob_score, object_fraction and the mode (``auto`` is resolved here).
        max_piece: detached pieces of more Gaussians than this stay (None: any size goes).
        rgb: ``[N, 3]`` base colours, input order, for the foreign-blob test and the oversized test's colour gate
            (None: neither).
        colour_gate: spare the oversized candidates of a neighbour's colour (without photos; photos judge them all).

    Returns:
        The decision, every field in the input order; pieces are numbered by their first Gaussian in that order
        (object mode keeps the first of equally large largest pieces).
    """
    order, neighbors, dist = graph.order, graph.neighbors, graph.dist
    ls = np.asarray(log_scales, dtype=np.float32)[order]
    with np.errstate(over="ignore"):  # a log scale of 1e30 is an infinite axis: it links to everything
        largest_axis = np.exp(_axis_extreme(ls, np.maximum))
    reach = largest_axis[neighbors]  # [N, K] becomes reach * (own + neighbour's largest axis), in place
    reach += largest_axis[:, None]
    reach *= np.float32(config.reach)
    linked = dist < reach
    del reach
    row_label, sizes = components(neighbors, linked)
    n = len(ls)
    label = np.empty(n, dtype=row_label.dtype)
    label[order] = row_label
    first = np.full(len(sizes), n, dtype=np.int64)
    np.minimum.at(first, label, np.arange(n))
    renumber = np.empty(len(sizes), dtype=label.dtype)
    renumber[np.argsort(first)] = np.arange(len(sizes), dtype=label.dtype)
    label, sizes = renumber[label], sizes[np.argsort(first)]
    largest_fraction = float(sizes.max() / n)
    mode, reason = choose_mode(config, largest_fraction)
    # per piece: detached from the content (object: not the largest; scene: under min_cluster), and going
    if mode == "object":
        candidate = np.arange(len(sizes)) != int(np.argmax(sizes))
    else:
        candidate = sizes < max(1.0, config.min_cluster * n)
    goes = candidate if max_piece is None else candidate & (sizes <= max_piece)
    detached = goes[label]
    spared = candidate & ~goes
    log_min, log_size = _axis_extreme(ls, np.minimum), ls.mean(axis=1)  # both tests use them
    row_scores = blob_scores(log_min, log_size, neighbors, dist)
    scores = np.empty(n, dtype=np.float32)
    scores[order] = row_scores
    oversized = (scores > config.blob_score) & ~detached
    colour_spared = foreign = 0
    foreign_mask = None
    if rgb is not None and colour_gate and config.blob_colour > 0:
        # only the candidates below blob_sure are asked (a few hundred): their colour against their neighbours'
        rows = np.flatnonzero(oversized[order] & (row_scores <= config.blob_sure))
        if rows.size:
            spare = rows[colour_gaps(rgb, order[rows], order[neighbors[rows]]) <= config.blob_colour]
            oversized[order[spare]] = False
            colour_spared = int(spare.size)
    if rgb is not None and config.foreign_size > 0:
        rows = large_round(ls, log_min, log_size, neighbors, ~(oversized | detached)[order], config.foreign_size)
        found = rows[colour_gaps(rgb, order[rows], order[neighbors[rows]]) > FOREIGN_COLOUR]
        oversized[order[found]] = True
        foreign = int(found.size)
        foreign_mask = np.zeros(n, dtype=bool)
        foreign_mask[order[found]] = True
    return LocalDecision(detached, oversized, label, sizes, scores, largest_fraction, mode, reason,
                         (int(spared.sum()), int(sizes[spared].sum())), colour_spared, foreign, foreign_mask)


def choose_mode(config: "PruneConfig", largest_fraction: float) -> tuple[str, str]:
    """Return the mode to run and why: ``auto`` becomes object when one piece holds ``object_fraction``."""
    if config.mode != "auto":
        return config.mode, f"--mode {config.mode} was asked for"
    if largest_fraction >= config.object_fraction:
        return "object", (f"auto: the largest connected piece holds {largest_fraction:.2%} of the Gaussians "
                          f"(>= {config.object_fraction:.0%}), so it is one object and what is detached from it goes")
    return "scene", (f"auto: the largest connected piece holds {largest_fraction:.2%} of the Gaussians "
                     f"(< {config.object_fraction:.0%}), so pieces under {config.min_cluster:.1%} go")


def _explain_decision(report: "PruneReport", decision: LocalDecision, config: "PruneConfig", max_piece: int | None,
                      one_colour: bool, photos_given: bool, background: str) -> None:
    """Say in ``report`` which mode the local tests ran in and why, what they spared and why (its ``mode_reason``,
    ``stayed`` and ``notes``)."""
    report.mode, report.mode_reason = decision.mode, decision.reason
    if decision.spared[0]:
        report.mode_reason += (f"; {decision.spared[1]:,} Gaussians in {decision.spared[0]:,} detached pieces of "
                               f"more than {max_piece} stay (no photos to judge them; --max-piece 0 removes them)")
    if one_colour and not photos_given:
        report.mode_reason += "; no colour test of the oversized Gaussians (the cloud is nearly one colour)"
    if decision.colour_spared:
        report.mode_reason += (f"; {decision.colour_spared:,} oversized Gaussians stay, each the colour of a "
                               f"neighbour (--blob-colour 0 removes them)")
    if decision.foreign:
        one = decision.foreign == 1
        report.mode_reason += (f"; {decision.foreign:,} round Gaussian{'' if one else 's'} over "
                               f"{config.foreign_size:g}x the median size, of a colour no neighbour has, "
                               f"{'put to the photos' if photos_given else 'goes' if one else 'go'} "
                               f"(--foreign-size 0 keeps {'it' if one else 'them'})")
    if background != "none":
        report.mode_reason += f"; {background}-background fog removed ({config.background} background)"
    if decision.spared[0]:
        report.stayed.append((DETACHED, decision.spared[1], f"in {decision.spared[0]:,} pieces of more than "
                              f"{max_piece} (no photos to judge them; --max-piece 0: they go)"))
    if decision.colour_spared:
        report.stayed.append((OVERSIZED, decision.colour_spared,
                              "of a neighbour's colour (--blob-colour 0: they go)"))
    if one_colour and not photos_given:
        report.notes.append("no colour test of the oversized Gaussians: the cloud is nearly one colour")


def _record_local_figures(report: "PruneReport", evaluated: np.ndarray, decision: LocalDecision,
                          config: "PruneConfig", photo_figures: dict[str, float]) -> None:
    """Fill ``report``'s per-Gaussian scores, threshold and statistics from the local tests' decision (the blob
    scores stand where the statistical rule has its mean distances, so the histogram shows them)."""
    report.evaluated = evaluated
    report.mean_distances = decision.blob_score
    report.first_mean_distances = decision.blob_score
    report.threshold = float(config.blob_score)
    report.thresholds = [report.threshold]
    report.iterations, report.converged = 1, True
    report.statistics = {"pieces": int(len(decision.component_sizes)), "largest_fraction": decision.largest_fraction,
                         "blob_score_median": float(np.median(decision.blob_score)),
                         "oversized_colour_spared": decision.colour_spared, "oversized_foreign": decision.foreign}
    report.statistics.update(photo_figures)


def _record_removals(report: "PruneReport", n: int, evaluated: np.ndarray, decision: LocalDecision,
                     config: "PruneConfig", max_piece: int | None, removed: dict[str, np.ndarray],
                     background: str) -> None:
    """Record in ``report`` what each test removes (``removed``: name -> ``[M]`` over the evaluated Gaussians) with
    a line saying what they are."""
    oversized = removed[OVERSIZED]
    piece = "pieces apart from the object" if decision.mode == "object" else \
        f"pieces under {config.min_cluster:.1%} of the Gaussians"
    if max_piece is not None:
        piece += f", of at most {max_piece} Gaussians"
    foreign_went = int((oversized & decision.foreign_mask).sum()) if decision.foreign_mask is not None else 0
    blobs = f"bigger than their spacing and neighbours (score > {config.blob_score:g})"
    if foreign_went:
        blobs = (f"{int(oversized.sum()) - foreign_went:,} bigger than their spacing and neighbours, {foreign_went:,} "
                 f"round blobs of a colour no neighbour has")
    for name, detail in ((DETACHED, piece), (OVERSIZED, blobs),
                         (FOG, f"faint, of the {background} training background's colour")):
        gone = np.zeros(n, dtype=bool)
        gone[evaluated[removed[name]]] = True
        report.remove(name, gone, detail)


def prune_cloud(cloud: GaussianCloud, config: "PruneConfig | None" = None, *, photos: "Photos | None" = None,
                renderer: Any = None, progress: ProgressFactory = null_progress, select: bool = True,
                **options: Any) -> "PruneResult":
    """Return the cloud without floaters in the config's mode, the keep mask ``[N]`` and a report (mode included).

    The default (``mode="auto"``) runs the local tests of this module; ``mode="statistical"`` is
    :func:`~roodi_toolkit.prune.outliers.remove_statistical_outliers` with the config's rule (``paper`` included,
    unchanged). Filters (NaN, opacity, box, sphere, value ranges) run first in every mode.

    With ``photos`` (the posed photos the cloud was trained on, :func:`~roodi_toolkit.prune.photos.find_photos`),
    the local modes keep every flagged Gaussian whose removal would make the photos worse
    (:mod:`~roodi_toolkit.prune.photos`); ``renderer`` renders them (default: the built-in one). The statistical
    mode ignores them.

    ``select=False`` leaves the result's cloud None in the local modes (the keep mask says what stays): a caller
    that writes the kept Gaussians itself (``write_cloud(cloud, path, rows=keep)``) saves a copy of the cloud.

    Raises:
        CloudError: NaN/Inf values without ``filter_nan``, or nothing left to evaluate.
        ConfigError: a bad option.

    Example:
        >>> from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud
        >>> planted = planted_floater_cloud(FloaterMix("torus", n_object=3000), seed=0)
        >>> pruned, keep, report = prune_cloud(planted.cloud)
        >>> report.mode, bool(keep[planted.labels == 0].all()), bool(keep[planted.labels == 2].mean() < 0.05)
        ('object', True, True)
    """
    config = config or PruneConfig()
    if options:
        config = replace(config, **options)
    if config.mode == "statistical":
        result = remove_statistical_outliers(cloud, config, progress=progress)
        result.report.mode_reason = "--mode statistical was asked for"
        return result
    t0 = time.perf_counter()
    n = len(cloud)
    report, keep, evaluated = filtered_report(cloud, config)
    if evaluated.size <= config.k:
        raise CloudError(f"only {evaluated.size} Gaussians left after the filters, the local tests need more than "
                         f"--k {config.k}; loosen the filters")
    sub = cloud.select(evaluated) if evaluated.size < n else cloud
    t1 = time.perf_counter()
    means = np.ascontiguousarray(sub.means, dtype=np.float32)
    graph = neighbour_graph(means, config.k, progress)
    report.timings["neighbours_and_distances"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    # without photos only the pieces too small to have structure go (PruneConfig.max_piece) and only the oversized
    # Gaussians of a colour foreign to their neighbours (PruneConfig.blob_colour); photos judge them all
    max_piece = None if photos is not None or config.max_piece == 0 else int(config.max_piece)
    asks_colour = (photos is None and config.blob_colour > 0) or config.foreign_size > 0
    rgb = sub.rgb if asks_colour else None
    one_colour = rgb is not None and not colours_vary(rgb, config.blob_colour or FOREIGN_COLOUR)
    decision = decide(sub.log_scales, graph, config, max_piece, None if one_colour else rgb, photos is None)
    fog, background = background_fog(sub, config.background, config.fog_tolerance)
    fog &= ~decision.flagged
    _explain_decision(report, decision, config, max_piece, one_colour, photos is not None, background)
    report.timings["rule"] = time.perf_counter() - t2
    detached, oversized, photo_figures = decision.detached, decision.oversized, {}
    if photos is not None and (decision.flagged | fog).any():
        supported, photo_figures = _photo_supported(sub, oversized | fog, detached, photos, renderer, progress, report)
        for name, flagged in ((DETACHED, detached), (OVERSIZED, oversized), (FOG, fog)):
            if (flagged & supported).any():
                report.stayed.append((name, int((flagged & supported).sum()), "the photos show them"))
        report.notes.append(f"photo check on {photos.source}: renders {photo_figures['photo_psnr']:.1f} dB")
        detached, oversized, fog = detached & ~supported, oversized & ~supported, fog & ~supported
    _record_local_figures(report, evaluated, decision, config, photo_figures)
    _record_removals(report, n, evaluated, decision, config, max_piece,
                     {DETACHED: detached, OVERSIZED: oversized, FOG: fog}, background)
    keep[evaluated[detached | oversized | fog]] = False
    t3 = time.perf_counter()
    out = None if not select else cloud.select(keep) if not keep.all() else cloud
    report.timings["select"] = time.perf_counter() - t3
    report.kept_count = int(keep.sum())
    report.timings["total"] = time.perf_counter() - t0
    return PruneResult(out, keep, report)


def _photo_supported(cloud: GaussianCloud, front: np.ndarray, behind: np.ndarray, photos: "Photos", renderer: Any,
                     progress: ProgressFactory, report: "PruneReport") -> tuple[np.ndarray, dict[str, float]]:
    """Return which flagged Gaussians the photos support (they stay) and the check's figures for the report's
    statistics; the check's time and description go into ``report``.

    Two passes: the check shares each pixel's change of error among all the flagged Gaussians there, so what lies
    behind a floater would share the floater's harm. The Gaussians that lie over the content (``front``: oversized
    blobs and fog) are judged first; those that go are left out when the rest (``behind``: detached pieces, a
    capture's sparse background among them) are judged.
    """
    from .photo_check import photo_support  # lazy: torch and the renderer load only when there are photos

    t0 = time.perf_counter()
    n = len(cloud)
    supported = np.zeros(n, dtype=bool)
    gone = np.zeros(n, dtype=bool)
    first = None  # the first pass sees the whole cloud: its fit to the photos is the one reported
    if front.any():
        first = photo_support(cloud, front, photos, renderer=renderer, progress=progress)
        supported |= front & (first.support > 0)
        gone = front & ~supported
    if behind.any():
        rest = np.flatnonzero(~gone)
        part = cloud.select(rest) if gone.any() else cloud
        check = photo_support(part, behind[rest], photos, renderer=renderer, progress=progress)
        supported[rest] |= behind[rest] & (check.support > 0)
        first = check if first is None else first
    check = first
    flagged = front | behind
    report.timings["photo_check"] = time.perf_counter() - t0
    figures = {"photo_views": check.views, "photo_flagged": int(flagged.sum()), "photo_supported": int(supported.sum()),
               "photo_psnr": round(check.psnr, 3), "photo_psnr_empty": round(check.psnr_empty, 3)}
    report.mode_reason += (f"; photo check on {photos.source}: {int(supported.sum()):,} of the {int(flagged.sum()):,} "
                           f"flagged Gaussians stay, the photos show them (renders {check.psnr:.1f} dB)")
    return supported, figures
