"""Statistical outlier removal of Gaussians (ROODI section 3.2) with the splat-transform style filters before it.

Semantics (as PCL / DESIGN.md): each Gaussian's K neighbours exclude the Gaussian itself (by index: duplicate
centres are neighbours at distance 0, never outliers for that); d_i is the mean distance to them; the paper's rule
keeps ``d_i <= mu + alpha * sigma`` with mu, sigma the mean and sample standard deviation (n-1) of the d_i.

Distances: ``w2`` (squared 2-Wasserstein, the paper's) or ``euclidean`` (plain centre distance, Open3D's).
Neighbours: ``centre`` (K nearest centres, as the paper) or ``w2`` (the exact K nearest under W2^2).

Rules (``docs/pruning.md`` has the measurements behind the default):

- ``paper``: one pass of mean + alpha * std.
- ``robust`` (default): threshold ``exp(median + alpha * 1.4826 * MAD)`` of log d_i, robust to the floaters
  themselves; then each Gaussian is re-evaluated against its K nearest Gaussians that are not flagged, until the
  flagged set is stable. Far floaters no longer inflate the statistics, and object Gaussians next to a floater are
  not removed because the floater raised their mean.
- ``clip``: mean + alpha * std re-estimated on the survivors (sigma clipping), with the same re-evaluation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ..errors import CloudError, ConfigError
from ..gaussians import GaussianCloud
from .filters import filtered_report
from .knn import CentreIndex, _drop_self, check_k, knn_w2
from ..progress import ProgressFactory, null_progress
from .wasserstein import gaussian_shapes, w2_sq_neighbors

DISTANCES = ("w2", "euclidean")
NEIGHBORS = ("centre", "w2")
RULES = ("robust", "paper", "clip")
MODES = ("auto", "scene", "object", "statistical")
VALUE_NAMES = ("x", "y", "z", "opacity", "scale", "min_scale")
"""Quantities ``value_ranges`` can bound: centre coordinates, linear opacity, largest and smallest linear scale."""
EXTRA_CANDIDATES = 8
"""Neighbours kept beyond K, so re-evaluating a Gaussian without its flagged neighbours needs no new search."""
MAD_TO_SIGMA = 1.4826
MEAN_AD_TO_SIGMA = math.sqrt(math.pi / 2)
"""Mean absolute deviation to standard deviation for a normal distribution (1.2533)."""
"""Scale factor that makes the median absolute deviation a consistent estimate of a normal's sigma."""

DEFAULT_ALPHA = {"robust": 3.5, "paper": 2.0, "clip": 3.0}
"""alpha per rule when none is given. robust: measured on the planted-floater benchmark (docs/pruning.md); paper:
the SOR convention (PCL tutorials, Open3D examples use 2.0; the paper does not publish its alpha); clip: 3-sigma
clipping."""


@dataclass(frozen=True)
class PruneConfig:
    """What :func:`remove_statistical_outliers` does, with the defaults and where they come from.

    Attributes:
        k: neighbours per Gaussian (not counting itself). 16: measured on the planted-floater benchmark; the paper
            does not publish K (docs/pruning.md).
        alpha: threshold multiplier; None picks the rule's default (:data:`DEFAULT_ALPHA`).
        distance: ``w2`` (paper) or ``euclidean`` (Open3D's statistical outlier removal).
        rule: ``robust`` (measured best, default), ``paper`` or ``clip``.
        neighbors: ``centre`` (paper: K nearest centres) or ``w2`` (exact K nearest under W2^2).
        max_iterations: re-evaluation rounds of the iterative rules.
        filter_nan: drop Gaussians with NaN/Inf values first (otherwise they are an error).
        min_opacity: drop Gaussians with sigmoid(opacity) below this (linear units), before the statistics.
        box: keep only centres inside (x0, y0, z0, x1, y1, z1), before the statistics.
        sphere: keep only centres inside (x, y, z, r), before the statistics.
        compute_dtype: float type of the W2 evaluation; float32 is within 1e-6 relative (wasserstein.py) and faster.
        mode: what :func:`roodi_toolkit.prune.scene.prune_cloud` runs: ``scene`` (local tests: detached pieces and
            oversized blobs, safe on real scenes), ``object`` (one object: what is detached from the largest
            piece goes, plus oversized blobs), ``statistical`` (the rule above: robust, paper or clip) or ``auto``
            (object when the largest piece holds ``object_fraction`` of the Gaussians, scene otherwise).
            :func:`remove_statistical_outliers` always runs the statistical rule.
        reach: link distance of the local tests, in sums of the two Gaussians' largest scales.
        min_cluster: scene mode removes pieces with fewer than this fraction of the Gaussians.
        max_piece: without photos, a detached piece goes only when it holds at most this many Gaussians (0: any
            size). Larger detached pieces have structure: real content that the linking rule split off (the real
            donut's inner pieces of 6-56 Gaussians, a cropped capture's chunks of 73-379), which only the photos
            can tell from a floater; with photos every detached piece is put to them.
        blob_score: oversized limit of the local tests (log units, see scene.py).
        blob_colour: without photos, an oversized candidate with a score up to ``blob_sure`` stays when one of its
            K neighbours has its base colour within this RGB distance (0-1 units; 0: colour is not asked); with
            photos every candidate is put to them. 0.12: measured on real splats (scene.py, docs/pruning.md).
        blob_sure: oversized candidates scoring above this go whatever their colour (log units).
        foreign_size: a round Gaussian whose smallest axis is more than this many times the scene's median
            Gaussian size (geometric mean of the scales), and more than its neighbours' median size, with a colour
            none of its neighbours has, goes as oversized whatever its score (a blob among large Gaussians scores
            low; 0: off). 6: planted blobs are 10-20x the median size; measured on real splats (scene.py).
        object_fraction: auto picks object mode when the largest piece holds at least this fraction.
        background: the colour the scene was trained on, whose fog the local modes remove: ``auto`` (detected,
            see scene.py), ``white``, ``black`` or ``none``.
        fog_tolerance: a Gaussian is background-coloured when every channel is within this of it.
        value_ranges: ``((name, low, high), ...)`` keep only Gaussians whose value lies in [low, high]; names in
            :data:`VALUE_NAMES`, before the statistics.
    """

    k: int = 16
    alpha: float | None = None
    distance: str = "w2"
    rule: str = "robust"
    neighbors: str = "centre"
    max_iterations: int = 8
    filter_nan: bool = False
    min_opacity: float | None = None
    box: tuple[float, float, float, float, float, float] | None = None
    sphere: tuple[float, float, float, float] | None = None
    compute_dtype: str = "float32"
    mode: str = "auto"
    reach: float = 1.5
    min_cluster: float = 0.001
    max_piece: int = 3
    blob_score: float = 0.5
    blob_colour: float = 0.12
    blob_sure: float = 2.0
    foreign_size: float = 6.0
    object_fraction: float = 0.98
    value_ranges: tuple[tuple[str, float, float], ...] = ()
    background: str = "auto"
    fog_tolerance: float = 0.05

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if not (np.isfinite(self.foreign_size) and (self.foreign_size == 0 or self.foreign_size >= 1)):
            raise ConfigError(f"foreign_size must be 0 (off) or a finite number >= 1, got {self.foreign_size}")
        if not (np.isfinite(self.blob_colour) and self.blob_colour >= 0) or np.isnan(self.blob_sure):
            raise ConfigError(f"blob_colour must be a finite number >= 0 and blob_sure a number, got "
                              f"{self.blob_colour} and {self.blob_sure}")
        for name, value in (("reach", self.reach), ("blob_score", self.blob_score)):
            if not np.isfinite(value) or (name == "reach" and value <= 0):
                raise ConfigError(f"{name} must be a {'positive' if name == 'reach' else 'finite'} number, "
                                  f"got {value}")
        if isinstance(self.max_piece, bool) or not isinstance(self.max_piece, (int, np.integer)) or self.max_piece < 0:
            raise ConfigError(f"max_piece must be a whole number >= 0 (0: no limit), got {self.max_piece!r}")
        if not 0 <= self.min_cluster < 1 or not 0 < self.object_fraction <= 1:
            raise ConfigError(f"min_cluster must be in [0, 1) and object_fraction in (0, 1], got {self.min_cluster} "
                              f"and {self.object_fraction}")
        if self.background not in ("auto", "white", "black", "none") or not 0 <= self.fog_tolerance < 0.5:
            raise ConfigError(f"background must be auto, white, black or none and fog_tolerance in [0, 0.5), got "
                              f"{self.background!r} and {self.fog_tolerance}")
        for entry in self.value_ranges:
            if len(entry) != 3 or entry[0] not in VALUE_NAMES or not float(entry[1]) <= float(entry[2]):
                raise ConfigError(f"a value range is (name, low, high) with name in {', '.join(VALUE_NAMES)} and "
                                  f"low <= high, got {entry}")
        if self.distance not in DISTANCES:
            raise ConfigError(f"distance must be one of {', '.join(DISTANCES)}, got {self.distance!r}")
        if self.rule not in RULES:
            raise ConfigError(f"rule must be one of {', '.join(RULES)}, got {self.rule!r}")
        if self.neighbors not in NEIGHBORS:
            raise ConfigError(f"neighbors must be one of {', '.join(NEIGHBORS)}, got {self.neighbors!r}")
        if self.neighbors == "w2" and self.distance != "w2":
            raise ConfigError("neighbors 'w2' needs distance 'w2'")
        if int(self.k) < 1:
            raise ConfigError(f"k must be at least 1, got {self.k}")
        if self.alpha is not None and not (np.isfinite(self.alpha) and self.alpha > 0):
            raise ConfigError(f"alpha must be a positive number, got {self.alpha}")
        if self.max_iterations < 1:
            raise ConfigError(f"max_iterations must be at least 1, got {self.max_iterations}")
        if self.min_opacity is not None and not (0 <= self.min_opacity < 1):
            raise ConfigError(f"min_opacity is a linear opacity in [0, 1), got {self.min_opacity}")
        if self.box is not None:
            b = tuple(float(v) for v in self.box)
            if len(b) != 6 or not all(np.isfinite(b)) or any(b[i] > b[i + 3] for i in range(3)):
                raise ConfigError(f"box must be x0,y0,z0,x1,y1,z1 with x0<=x1, y0<=y1, z0<=z1, got {self.box}")
        if self.sphere is not None:
            s = tuple(float(v) for v in self.sphere)
            if len(s) != 4 or not all(np.isfinite(s)) or s[3] < 0:
                raise ConfigError(f"sphere must be x,y,z,r with r >= 0, got {self.sphere}")
        if self.compute_dtype not in ("float32", "float64"):
            raise ConfigError(f"compute_dtype must be float32 or float64, got {self.compute_dtype!r}")

    @property
    def effective_alpha(self) -> float:
        """alpha, or the rule's default when alpha is None."""
        return float(self.alpha) if self.alpha is not None else DEFAULT_ALPHA[self.rule]


@dataclass
class PruneReport:
    """What pruning did.

    Attributes:
        input_count: Gaussians in.
        stages: ``[(name, removed), ...]`` in order: nonfinite, min_opacity, box, sphere, value ranges, then
            statistical (statistical mode) or detached and oversized (scene and object modes).
        mode: the mode that ran (``auto`` resolved) and ``mode_reason`` why.
        kept_count: Gaussians out.
        threshold: final threshold on d_i (units of the distance: W2^2 or plain length).
        thresholds: threshold of every round of the rule (one for ``paper``).
        iterations: rounds the rule ran.
        converged: whether the flagged set stopped changing before max_iterations.
        statistics: ``{"mean", "std", "median", "mad"}`` of the first-round d_i (mad of log d_i).
        config: the configuration as a dict (alpha resolved).
        timings: seconds per step.
        evaluated: ``[M]`` indices into the input cloud of the Gaussians that reached the statistics.
        mean_distances: ``[M]`` the d_i each decision used (flagged exactly where it exceeds ``threshold``): for the
            robust rule, the value of the round that last re-evaluated a Gaussian the first round flagged (for
            isolated floaters a proven lower bound already above the threshold), the first-round value otherwise.
        first_mean_distances: ``[M]`` d_i of the first round (the paper's quantity).
        removed_by: ``[N]`` int16, for each input Gaussian the index in ``stages`` of the stage that removed it, -1
            for the kept (:meth:`remove`); the floater picture colours by it.
        details: ``{stage: what went}`` in a few words, for the summary (e.g. "pieces of at most 3 Gaussians").
        stayed: ``[(stage, count, why), ...]``: Gaussians a test flagged that stay, and why (a neighbour's colour,
            no photos to judge a large piece, the photos show them); they are among the kept.
        notes: short remarks on what did not run or what the cloud is (one line each).
    """

    input_count: int
    stages: list[tuple[str, int]] = field(default_factory=list)
    kept_count: int = 0
    threshold: float = float("nan")
    thresholds: list[float] = field(default_factory=list)
    iterations: int = 0
    converged: bool = True
    statistics: dict[str, float] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    evaluated: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    mean_distances: np.ndarray = field(default_factory=lambda: np.zeros(0))
    first_mean_distances: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mode: str = "statistical"
    mode_reason: str = ""
    removed_by: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int16))
    details: dict[str, str] = field(default_factory=dict)
    stayed: list[tuple[str, int, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def remove(self, stage: str, removed: np.ndarray, detail: str = "") -> None:
        """Append ``stage`` with the Gaussians it removes (``[N]`` bool over the input, none removed before)."""
        if self.removed_by.shape != (self.input_count,):
            self.removed_by = np.full(self.input_count, -1, dtype=np.int16)
        self.removed_by[removed] = len(self.stages)
        self.stages.append((stage, int(np.count_nonzero(removed))))
        if detail:
            self.details[stage] = detail

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-ready summary (counts per stage, thresholds, timings; no per-Gaussian arrays)."""
        return {
            "input_count": self.input_count,
            "mode": self.mode,
            "mode_reason": self.mode_reason,
            "stages": [{"stage": name, "removed": int(n)} for name, n in self.stages],
            "removed_count": self.input_count - self.kept_count,
            "kept_count": self.kept_count,
            "removed_details": dict(self.details),
            "flagged_but_kept": [{"stage": name, "count": int(n), "why": why} for name, n, why in self.stayed],
            "notes": list(self.notes),
            "threshold": self.threshold,
            "thresholds": self.thresholds,
            "iterations": self.iterations,
            "converged": self.converged,
            "statistics": self.statistics,
            "config": self.config,
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
        }


class PruneResult(NamedTuple):
    """The pruned cloud, the keep mask ``[N]`` over the input, and the report (unpacks like Open3D's filters). The
    cloud is None where the caller asked for the mask only (:func:`~roodi_toolkit.prune.scene.prune_cloud`'s
    ``select``)."""

    cloud: GaussianCloud | None
    keep_mask: np.ndarray
    report: PruneReport


# ------------------------------------------------------------------------------------------------------ distances
@dataclass
class _Memo:
    """The last re-evaluation: its flags and threshold, the values, which rows were affected, which needed wide search."""

    flagged: np.ndarray
    threshold: float | None
    mean: np.ndarray
    affected: np.ndarray
    wide: np.ndarray


class _WideCache:
    """The ``width`` nearest centres of rows searched so far, found once per row and then reused.

    The same rows (isolated floaters, Gaussians beside a flagged cluster) need the wider search in several rounds
    of the rule; the candidate list does not depend on which Gaussians are flagged, only its use does.
    """

    def __init__(self, n: int, width: int) -> None:
        self.width = width
        self.slot = np.full(n, -1, dtype=np.int64)
        self.idx = np.zeros((0, width), dtype=np.int32)
        self.dist2 = np.zeros((0, width), dtype=np.float32)

    def get(self, rows: np.ndarray, index: CentreIndex, means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return candidates ``[R, width]`` (sorted by distance) and their squared distances for ``rows``."""
        new = rows[self.slot[rows] < 0]
        if new.size:
            idx, dist2 = index.query(means[new], self.width)
            self.slot[new] = len(self.idx) + np.arange(len(new))
            self.idx = np.concatenate([self.idx, idx.astype(np.int32)])
            self.dist2 = np.concatenate([self.dist2, dist2.astype(np.float32)])
        at = self.slot[rows]
        return self.idx[at], self.dist2[at]


class NeighborDistances:
    """Per-Gaussian distances to K neighbours, and the machinery to re-evaluate them against a subset.

    Args:
        cloud: the Gaussians (finite).
        config: distance, neighbours, K, dtype.
        progress: progress factory.
    """

    def __init__(self, cloud: GaussianCloud, config: PruneConfig, progress: ProgressFactory = null_progress) -> None:
        self.config = config
        self.k = int(config.k)
        self.means = np.ascontiguousarray(cloud.means, dtype=np.float32)
        self.progress = progress
        check_k(self.k, len(self.means))
        dtype = np.float32 if config.compute_dtype == "float32" else np.float64
        self.shapes = gaussian_shapes(cloud.quats_wxyz, cloud.log_scales, dtype) if config.distance == "w2" else None
        self.index = CentreIndex(self.means)
        if config.neighbors == "w2":
            self.neighbors, dist = knn_w2(self.means, self.shapes, self.k, index=self.index, progress=progress)
            self.candidates = None
        else:
            # K + EXTRA_CANDIDATES neighbours: re-evaluating without flagged ones then rarely needs a new search
            extra = min(EXTRA_CANDIDATES, len(self.means) - 1 - self.k)
            self.candidates, self.candidate_dist2 = self.index.knn_all(self.k + extra, progress=progress)
            self.neighbors = self.candidates[:, :self.k]
            dist = self._distances(self.neighbors, self.candidate_dist2[:, :self.k], np.arange(len(self.means)))
            self._candidate_dist = np.full(self.candidates.shape, np.nan, dtype=dist.dtype)
            self._candidate_dist[:, :self.k] = dist
        self.mean = dist.mean(axis=1, dtype=np.float64)
        # wider searches for rows with many flagged candidates: 2x, then 4x (K + EXTRA), each cached per row
        widths = sorted({min(f * (self.k + EXTRA_CANDIDATES), len(self.means) - 1) for f in (2, 4)})
        self._wide = [_WideCache(len(self.means), w) for w in widths]
        self._memo: _Memo | None = None

    def _distances(self, neighbors: np.ndarray, dist2: np.ndarray, rows: np.ndarray) -> np.ndarray:
        if self.config.distance == "w2":
            return w2_sq_neighbors(self.means, self.shapes, neighbors, dist2=dist2, rows=rows,
                                   progress=self.progress if len(rows) > (1 << 16) else null_progress)
        # plain distances in float64 from the float32 centres, as Open3D computes them
        diff = self.means[neighbors].astype(np.float64) - self.means[rows][:, None, :].astype(np.float64)
        return np.sqrt(np.einsum("rkc,rkc->rk", diff, diff))

    def mean_excluding(self, flagged: np.ndarray, threshold: float | None = None,
                       only: np.ndarray | None = None) -> np.ndarray:
        """Return d_i ``[N]`` with each Gaussian's K neighbours taken among the Gaussians not flagged.

        Rows whose first-round neighbours are all unflagged keep their first-round value (their K nearest are
        the same); the others are searched again in a tree over the unflagged Gaussians.

        With a ``threshold``, a row whose unflagged neighbours all lie beyond a wider search (an isolated floater
        among other floaters) gets the lower bound that search proves, when that bound already exceeds the threshold:
        its decision is exact, its value an underestimate, and no tree over the unflagged Gaussians is built for it.

        With ``only`` (a mask), just those rows are re-evaluated; the others keep their first-round value.
        """
        mean = self.mean.copy()
        survivors = np.flatnonzero(~flagged)
        if len(survivors) <= self.k:
            return np.full_like(mean, np.inf)
        affected_mask = flagged[self.neighbors].any(axis=1)
        if only is not None:
            affected_mask &= only
        affected = np.flatnonzero(affected_mask)
        if affected.size == 0:
            return mean
        if self.config.neighbors == "w2":
            mean[affected] = self._w2_neighbors_among(survivors, CentreIndex(self.means[survivors]), affected)
            return mean
        memo = self._memo
        if memo is not None and memo.threshold == threshold and not (flagged & ~memo.flagged).any():
            # only flags were cleared since the last call: a row's value can change only if one of its stored
            # candidates was cleared, or if it needed the wider searches (whose candidates are not tracked)
            cleared = memo.flagged & ~flagged
            mean = memo.mean.copy()
            gone = memo.affected & ~affected_mask
            mean[gone] = self.mean[gone]
            wide = memo.wide & affected_mask
            affected = affected[cleared[self.candidates[affected]].any(axis=1) | wide[affected]]
        else:
            wide = np.zeros(len(mean), dtype=bool)
        wide[affected] = False
        wide[self._mean_among_unflagged(mean, affected, flagged, survivors, threshold)] = True
        self._memo = _Memo(flagged.copy(), threshold, mean.copy(), affected_mask, wide)
        return mean

    def _mean_among_unflagged(self, mean: np.ndarray, affected: np.ndarray, flagged: np.ndarray,
                              survivors: np.ndarray, threshold: float | None) -> np.ndarray:
        """Fill ``mean`` at ``affected`` rows from their K nearest unflagged; return the rows that needed wider search."""
        if affected.size == 0:
            return affected
        # the K nearest unflagged among the stored K + EXTRA_CANDIDATES (exact while at most EXTRA are flagged)
        cand = self.candidates[affected]
        missing = np.isnan(self._candidate_dist[affected, self.k:]).any(axis=1)
        if missing.any():
            rows = affected[missing]
            self._candidate_dist[rows, self.k:] = self._distances(
                self.candidates[rows, self.k:], self.candidate_dist2[rows, self.k:], rows)
        usable = ~flagged[cand]
        enough = usable.sum(axis=1) >= self.k
        rank = np.cumsum(usable, axis=1)
        take = usable & (rank <= self.k)
        values = np.where(take, self._candidate_dist[affected], 0).sum(axis=1, dtype=np.float64)
        mean[affected[enough]] = values[enough] / self.k
        rest = wide_rows = affected[~enough]
        for wide in self._wide:  # many flagged nearby: wider searches in the full tree, skipping the flagged
            if not rest.size:
                break
            idx, dist2 = wide.get(rest, self.index, self.means)
            usable = ~flagged[idx] & (idx != rest[:, None])
            enough = usable.sum(axis=1) >= self.k
            ok = rest[enough]
            if ok.size:
                order = np.argsort(~usable[enough], axis=1, kind="stable")[:, :self.k]  # first K usable, in order
                nb = np.take_along_axis(idx[enough], order, axis=1)
                d2 = np.take_along_axis(dist2[enough], order, axis=1)
                mean[ok] = self._distances(nb, d2, ok).mean(axis=1, dtype=np.float64)
            if threshold is not None:
                # every unflagged neighbour is at least as far as the last candidate: W2^2 >= |mu_i - mu_j|^2
                far2 = dist2[~enough, -1].astype(np.float64)
                bound = far2 if self.config.distance == "w2" else np.sqrt(far2)
                decided = bound > threshold
                mean[rest[~enough][decided]] = bound[decided]
                enough[np.flatnonzero(~enough)[decided]] = True
            rest = rest[~enough]
        if rest.size:  # inside a flagged cluster: search a tree over the unflagged Gaussians
            sub = CentreIndex(self.means[survivors])
            position = np.full(len(self.means), -1, dtype=np.int64)
            position[survivors] = np.arange(len(survivors))
            idx, dist2 = sub.query(self.means[rest], self.k + 1)
            idx, dist2 = _drop_self(idx, dist2, position[rest])
            mean[rest] = self._distances(survivors[idx], dist2, rest).mean(axis=1, dtype=np.float64)
        return wide_rows

    def _w2_neighbors_among(self, survivors: np.ndarray, sub: CentreIndex, rows: np.ndarray) -> np.ndarray:
        """Return mean W2^2 to the exact K nearest (under W2^2) unflagged Gaussians, for ``rows``."""
        out = np.empty(len(rows))
        is_survivor = np.zeros(len(self.means), dtype=bool)
        is_survivor[survivors] = True
        m = 2 * self.k + 1
        todo = np.arange(len(rows))
        while todo.size:
            m_eff = min(m, len(survivors))
            idx, d2 = sub.query(self.means[rows[todo]], m_eff)
            cand = survivors[idx]
            w2 = w2_sq_neighbors(self.means, self.shapes, cand, dist2=d2, rows=rows[todo])
            w2[cand == rows[todo][:, None]] = np.inf
            best = np.sort(w2, axis=1)[:, :self.k]
            certified = (m_eff >= len(survivors)) | (d2[:, -1] >= best[:, -1])
            out[todo[certified]] = best[certified].mean(axis=1, dtype=np.float64)
            todo = todo[~certified]
            m *= 2
        return out


# ------------------------------------------------------------------------------------------------------ rules
def paper_threshold(d: np.ndarray, alpha: float) -> float:
    """Return mean + alpha * sample std (n-1) of d: the paper's (and PCL's) threshold."""
    d = np.asarray(d, dtype=np.float64)
    std = float(d.std(ddof=1)) if len(d) > 1 else 0.0
    return float(d.mean() + alpha * std)


def robust_threshold(d: np.ndarray, alpha: float) -> tuple[float, float, float]:
    """Return ``(threshold, median, mad)``: exp(median + alpha * 1.4826 * MAD) over log d (d > 0 only).

    Log distances: W2^2 spans orders of magnitude and its log is close to symmetric on a surface, so a robust
    centre and spread of log d describe the object's Gaussians whatever the floaters do. When the MAD is zero (more
    than half the distances equal), the mean absolute deviation about the median stands in for it.
    """
    d = np.asarray(d, dtype=np.float64)
    pos = d[d > 0]
    if pos.size == 0:
        return 0.0, float("-inf"), 0.0
    logs = np.log(pos)
    med = float(np.median(logs))
    dev = np.abs(logs - med)
    mad = float(np.median(dev))
    spread = MAD_TO_SIGMA * mad
    if spread == 0.0:
        # over half the distances are equal (regular grids, duplicated structure): the MAD says nothing about the
        # rest, so use the mean absolute deviation (x1.2533 for a normal's sigma); zero only if all are equal
        spread = MEAN_AD_TO_SIGMA * float(dev.mean())
    return float(np.exp(med + alpha * spread)), med, mad


def outlier_mask(dist: NeighborDistances, config: PruneConfig, report: PruneReport | None = None) -> np.ndarray:
    """Return the flagged (outlier) mask ``[N]`` of the config's rule, filling the report's thresholds and statistics.

    ``dist`` can be reused across rules and alphas with the same K, distance and neighbours (benchmarks do).
    """
    report = report if report is not None else PruneReport(input_count=len(dist.mean))
    alpha = config.effective_alpha
    d0 = dist.mean
    log_med, log_mad = robust_threshold(d0, 1.0)[1:]
    report.statistics = {"mean": float(d0.mean()), "std": float(d0.std(ddof=1)) if len(d0) > 1 else 0.0,
                         "median": float(np.median(d0)), "log_median": log_med, "log_mad": log_mad}
    report.first_mean_distances = d0
    if config.rule == "paper":
        threshold = paper_threshold(d0, alpha)
        report.thresholds = [threshold]
        report.threshold, report.iterations, report.converged = threshold, 1, True
        report.mean_distances = d0
        return d0 > threshold

    if config.rule == "robust":
        threshold = robust_threshold(d0, alpha)[0]
    else:
        threshold = paper_threshold(d0, alpha)
    flagged = d0 > threshold
    decided = d0.copy()  # the distance each Gaussian's current decision rests on
    report.thresholds = [threshold]
    d = d0
    converged = False
    for _ in range(config.max_iterations):
        # the robust rule's threshold is fixed, so rows decided by a distance bound need no exact value
        if config.rule == "robust":
            # only flagged Gaussians can change their decision, so only they are re-evaluated
            d = dist.mean_excluding(flagged, threshold, only=flagged)
        else:
            d = dist.mean_excluding(flagged)
        if config.rule == "clip":
            threshold = paper_threshold(d[~flagged], alpha)
            new = d > threshold
            decided = d
        else:
            decided[flagged] = d[flagged]
            # robust: later rounds only clear Gaussians whose distance was raised by a flagged neighbour; adding
            # flags would let the rule erode a cloud from its boundary inwards, layer by layer
            new = flagged & (d > threshold)
        report.thresholds.append(threshold)
        if np.array_equal(new, flagged):
            converged = True
            break
        flagged = new
    report.threshold, report.iterations, report.converged = threshold, len(report.thresholds), converged
    report.mean_distances = decided
    return flagged


# ------------------------------------------------------------------------------------------------------ API
def remove_statistical_outliers(cloud: GaussianCloud, config: PruneConfig | None = None, *,
                                progress: ProgressFactory = null_progress, **options: Any) -> PruneResult:
    """Return the cloud without statistical outliers (after the filters), the keep mask and a report.

    Args:
        cloud: the Gaussians; every column, extras included, is carried to the output in input order.
        config: a :class:`PruneConfig`; keyword ``options`` override its fields (``k=16, alpha=4.0, ...``).
        progress: progress factory for the long steps.

    Returns:
        ``PruneResult(cloud, keep_mask, report)``; ``keep_mask`` is ``[N]`` bool over the input.

    Raises:
        CloudError: NaN/Inf values without ``filter_nan``, or nothing left to evaluate.
        ConfigError: a bad option (unknown rule, k >= remaining Gaussians, ...).

    Example:
        >>> from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud
        >>> planted = planted_floater_cloud(FloaterMix("sphere", n_object=3000), seed=0)
        >>> pruned, keep, report = remove_statistical_outliers(planted.cloud, k=16)
        >>> bool(keep[planted.labels == 0].mean() > 0.99), bool(keep[planted.labels != 0].mean() < 0.05)
        (True, True)
    """
    config = config or PruneConfig()
    if options:
        from dataclasses import replace

        config = replace(config, **options)
    t0 = time.perf_counter()
    n = len(cloud)
    report, keep, evaluated = filtered_report(cloud, config)
    if evaluated.size == 0:
        raise CloudError("no Gaussians left after the filters; loosen --min-opacity, --filter-box or --filter-sphere")
    sub = cloud.select(evaluated) if evaluated.size < n else cloud
    t1 = time.perf_counter()
    dist = NeighborDistances(sub, config, progress=progress)
    report.timings["neighbours_and_distances"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    flagged = outlier_mask(dist, config, report)
    report.timings["rule"] = time.perf_counter() - t2
    report.evaluated = evaluated
    keep[evaluated[flagged]] = False
    measure = "W2²" if config.distance == "w2" else "distance"
    report.remove("statistical", ~keep & (report.removed_by < 0), f"mean {measure} to {config.k} neighbours above "
                  f"{report.threshold:.4g} (rule {config.rule}, alpha {config.effective_alpha:g})")
    t3 = time.perf_counter()
    out = cloud.select(keep)
    report.timings["select"] = time.perf_counter() - t3
    report.kept_count = len(out)
    report.timings["total"] = time.perf_counter() - t0
    return PruneResult(out, keep, report)
