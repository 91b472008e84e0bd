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
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import CloudError
from ..gaussians import GaussianCloud
from ..progress import ProgressFactory, null_progress
# the settings and the report, importable from here as before
from .config import (DEFAULT_ALPHA, DISTANCES, MODES, NEIGHBORS, RULES, VALUE_NAMES, PruneConfig,  # noqa: F401
                     PruneReport, PruneResult)
from .filters import filtered_report
from .knn import CentreIndex, _drop_self, check_k, knn_w2
from .wasserstein import gaussian_shapes, w2_sq_neighbors

EXTRA_CANDIDATES = 8
"""Neighbours kept beyond K, so re-evaluating a Gaussian without its flagged neighbours needs no new search."""
MAD_TO_SIGMA = 1.4826
"""Scale factor that makes the median absolute deviation a consistent estimate of a normal's sigma."""
MEAN_AD_TO_SIGMA = math.sqrt(math.pi / 2)
"""Mean absolute deviation to standard deviation for a normal distribution (1.2533)."""


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
