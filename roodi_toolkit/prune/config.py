"""The settings and the report of outlier removal, which the filters (:mod:`roodi_toolkit.prune.filters`) and the
statistical rules (:mod:`roodi_toolkit.prune.outliers`, where every name here is importable as before) share.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ..errors import ConfigError
from ..gaussians import GaussianCloud

DISTANCES = ("w2", "euclidean")
NEIGHBORS = ("centre", "w2")
RULES = ("robust", "paper", "clip")
MODES = ("auto", "scene", "object", "statistical")
VALUE_NAMES = ("x", "y", "z", "opacity", "scale", "min_scale")
"""Quantities ``value_ranges`` can bound: centre coordinates, linear opacity, largest and smallest linear scale."""

DEFAULT_ALPHA = {"robust": 3.5, "paper": 2.0, "clip": 3.0}
"""alpha per rule when none is given. robust: measured on the planted-floater benchmark (docs/pruning.md); paper:
the SOR convention (PCL tutorials, Open3D examples use 2.0; the paper does not publish its alpha); clip: 3-sigma
clipping."""


@dataclass(frozen=True)
class PruneConfig:
    """What :func:`~roodi_toolkit.prune.outliers.remove_statistical_outliers` does, with the defaults and where they
    come from.

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
