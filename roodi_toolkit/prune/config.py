"""The settings and the report of outlier removal, which the filters (:mod:`roodi_toolkit.prune.filters`) and the
statistical rules (:mod:`roodi_toolkit.prune.outliers`, where every name here is importable as before) share.

Each setting is declared once, in its field (:func:`roodi_toolkit.settings.setting`: default, range, help, option
name); the commands' options are made from these fields (``roodi_toolkit.cli.settings``). The settings are split by
what uses them: :class:`NeighbourSettings` (both rules), :class:`StatisticalSettings` (ROODI 3.2's rule),
:class:`FilterSettings` (before every rule), :class:`LocalSettings` (the mode, and the scene and object modes' local
tests in :mod:`roodi_toolkit.prune.scene`) and :class:`PhotoSettings` (the photo check); :class:`PruneConfig` is all
but the photo check in one object, as :func:`~roodi_toolkit.prune.scene.prune_cloud` takes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..settings import check_settings, documented, parse_floats, setting

DISTANCES = ("w2", "euclidean")
NEIGHBORS = ("centre", "w2")
RULES = ("robust", "paper", "clip")
MODES = ("auto", "scene", "object", "statistical")
BACKGROUNDS = ("auto", "white", "black", "none")
VALUE_NAMES = ("x", "y", "z", "opacity", "scale", "min_scale")
"""Quantities ``value_ranges`` can bound: centre coordinates, linear opacity, largest and smallest linear scale."""

DEFAULT_ALPHA = {"robust": 3.5, "paper": 2.0, "clip": 3.0}
"""alpha per rule when none is given. robust: measured on the planted-floater benchmark (docs/pruning.md); paper:
the SOR convention (PCL tutorials, Open3D examples use 2.0; the paper does not publish its alpha); clip: 3-sigma
clipping."""


def parse_value_range(text: str) -> tuple[str, float, float]:
    """Return ``(name, low, high)`` from ``NAME,MIN,MAX`` (``--filter-value``).

    Raises:
        ValueError: an unknown NAME, MIN or MAX not finite numbers, or MIN above MAX.
    """
    name, _, rest = str(text).partition(",")
    if name not in VALUE_NAMES:
        raise ValueError(f"{text!r}: NAME must be one of {', '.join(VALUE_NAMES)}")
    low, high = parse_floats(rest, 2)
    if not low <= high:
        raise ValueError(f"{text!r}: MIN must not exceed MAX")
    return name, float(low), float(high)


@documented
@dataclass(frozen=True)
class NeighbourSettings:
    """The neighbourhood both rules judge a Gaussian by."""

    # 16: measured on the planted-floater benchmark; the paper does not publish K (docs/pruning.md)
    k: int = setting(16, "Neighbours per Gaussian, not counting itself.", low=1)

    def __post_init__(self) -> None:
        check_settings(self)


@documented
@dataclass(frozen=True)
class StatisticalSettings(NeighbourSettings):
    """ROODI section 3.2's statistical rule (:func:`~roodi_toolkit.prune.outliers.remove_statistical_outliers`).
    Giving one of its options on the command line asks for this rule (``--mode auto`` becomes ``statistical``)."""

    alpha: float | None = setting(None, "Threshold multiplier. Default per rule: robust 3.5, paper 2, clip 3.",
                                  low=0, low_open=True)
    distance: str = setting("w2", "w2: squared 2-Wasserstein between Gaussians (paper); euclidean: plain centre "
                            "distance (Open3D).", choices=DISTANCES)
    rule: str = setting("robust", "robust: median/MAD of log distances, re-evaluated without flagged neighbours; "
                        "paper: one pass of mean + alpha * std; clip: iterated mean + alpha * std.", choices=RULES)
    neighbors: str = setting("centre", "centre: K nearest centres (paper); w2: exact K nearest under W2 (slower).",
                             choices=NEIGHBORS)
    max_iterations: int = setting(8, "Re-evaluation rounds of the iterative rules.", low=1, cli=False)
    # float32 is within 1e-6 relative of float64 (wasserstein.py) and faster
    compute_dtype: str = setting("float32", "Float type of the W2 evaluation.", choices=("float32", "float64"),
                                 cli=False)

    def __post_init__(self) -> None:
        check_settings(self)
        self._check_statistical()

    def _check_statistical(self) -> None:
        if self.neighbors == "w2" and self.distance != "w2":
            raise ConfigError("neighbors 'w2' needs distance 'w2'")

    @property
    def effective_alpha(self) -> float:
        """alpha, or the rule's default when alpha is None."""
        return float(self.alpha) if self.alpha is not None else DEFAULT_ALPHA[self.rule]


@documented
@dataclass(frozen=True)
class FilterSettings:
    """The filters every mode runs first (:mod:`roodi_toolkit.prune.filters`)."""

    filter_nan: bool = setting(False, "Drop Gaussians with NaN/Inf values (otherwise they are an error).")
    min_opacity: float | None = setting(None, "Drop Gaussians whose opacity (linear, after sigmoid) is below this, "
                                        "e.g. 0.0039 = 1/255.", low=0, high=1, high_open=True)
    box: tuple[float, float, float, float, float, float] | None = setting(
        None, "Keep only Gaussians whose centre is inside this axis-aligned box.", option="--filter-box",
        metavar="X0,Y0,Z0,X1,Y1,Z1")
    sphere: tuple[float, float, float, float] | None = setting(
        None, "Keep only Gaussians whose centre is inside this sphere.", option="--filter-sphere", metavar="X,Y,Z,R")
    value_ranges: tuple[tuple[str, float, float], ...] = setting(
        (), "Keep only Gaussians with NAME in [MIN, MAX]; NAME is x, y, z, opacity (linear), scale (largest axis) or "
        "min_scale. Repeatable.", option="--filter-value", metavar="NAME,MIN,MAX", parse=parse_value_range)

    def __post_init__(self) -> None:
        check_settings(self)
        self._check_filters()

    def _check_filters(self) -> None:
        if self.box is not None and any(float(self.box[i]) > float(self.box[i + 3]) for i in range(3)):
            raise ConfigError(f"box must be x0,y0,z0,x1,y1,z1 with x0<=x1, y0<=y1, z0<=z1, got {self.box}")
        if self.sphere is not None and float(self.sphere[3]) < 0:
            raise ConfigError(f"sphere must be x,y,z,r with r >= 0, got {self.sphere}")
        for entry in self.value_ranges:
            if len(entry) != 3 or entry[0] not in VALUE_NAMES or not float(entry[1]) <= float(entry[2]):
                raise ConfigError(f"a value range is (name, low, high) with name in {', '.join(VALUE_NAMES)} and "
                                  f"low <= high, got {entry}")


MODE_HELP = ("scene: remove pieces detached from the content and oversized blobs, judged locally (safe on real "
             "scenes); object: one object, what is detached from it goes (see --max-piece); statistical: the global "
             "rule of --rule (paper: ROODI 3.2 as published); auto: object or scene, the choice is printed and "
             "reported. Giving --rule, --alpha, --distance or --neighbors with auto implies statistical.")


@documented
@dataclass(frozen=True)
class LocalSettings:
    """The mode :func:`~roodi_toolkit.prune.scene.prune_cloud` runs, and the settings of its local tests (scene and
    object modes: detached pieces and oversized blobs on the neighbour graph, see scene.py and docs/pruning.md)."""

    mode: str = setting("auto", MODE_HELP, choices=MODES)
    reach: float = setting(1.5, "scene/object: two Gaussians are connected when their centres are closer than this "
                           "many sums of their largest scales.", low=0, low_open=True)
    min_cluster: float = setting(0.001, "scene: remove connected pieces with fewer than this fraction of the "
                                 "Gaussians.", low=0, high=1, high_open=True)
    # larger detached pieces have structure: real content the linking rule split off (the real donut's inner pieces
    # of 6-56 Gaussians, a cropped capture's chunks of 73-379), which only the photos can tell from a floater
    max_piece: int = setting(3, "scene/object without photos: a detached piece goes only when it holds at most this "
                             "many Gaussians (larger ones are often real content split off); 0: any size. With "
                             "photos every detached piece is put to them.", low=0)
    blob_score: float = setting(0.5, "scene/object: remove Gaussians whose smallest axis exceeds the local spacing "
                                "and size by more than this (log units; higher keeps more).")
    # 0.12: measured on real splats (scene.py, docs/pruning.md)
    blob_colour: float = setting(0.12, "scene/object without photos: an oversized Gaussian stays when one of its "
                                 "neighbours has its base colour within this RGB distance (0-1 units) and it scores "
                                 "at most --blob-sure; 0: colour is not asked. With photos every oversized Gaussian "
                                 "is put to them.", low=0)
    blob_sure: float = setting(2.0, "scene/object without photos: oversized Gaussians scoring above this go "
                               "whatever their colour.", finite=False)
    # 6: planted blobs are 10-20x the median size; measured on real splats (scene.py). A blob among large Gaussians
    # scores low, hence this test beside the score.
    foreign_size: float = setting(6.0, "scene/object: a round Gaussian whose smallest axis is over this many times "
                                  "the scene's median Gaussian size (and over its neighbours' median size), with a "
                                  "colour none of its neighbours has, is oversized whatever its score (a blob among "
                                  "large Gaussians); 0: off. With photos it is put to them.", low=0)
    object_fraction: float = setting(0.98, "auto picks object mode when the largest piece holds at least this "
                                     "fraction of the Gaussians.", low=0, high=1, low_open=True, cli=False)
    background: str = setting("auto", "scene/object: the solid background the scene was trained on; its colour's "
                              "faint fog goes. auto: detected (a wide, faint cloud of exactly white or black "
                              "Gaussians).", choices=BACKGROUNDS)
    fog_tolerance: float = setting(0.05, "A Gaussian is background-coloured when every channel is within this of "
                                   "the background.", low=0, high=0.5, high_open=True, cli=False)

    def __post_init__(self) -> None:
        check_settings(self)
        self._check_local()

    def _check_local(self) -> None:
        if 0 < self.foreign_size < 1:
            raise ConfigError(f"foreign_size must be 0 (off) or a finite number >= 1, got {self.foreign_size}")


@documented
@dataclass(frozen=True)
class PruneConfig(LocalSettings, FilterSettings, StatisticalSettings):
    """What :func:`~roodi_toolkit.prune.scene.prune_cloud` and
    :func:`~roodi_toolkit.prune.outliers.remove_statistical_outliers` do: the settings of the neighbourhood, the
    statistical rule, the filters and the local tests in one object (each field's help says what it does, the
    comments beside the fields where the defaults come from). ``remove_statistical_outliers`` always runs the
    statistical rule, whatever ``mode``.
    """

    def __post_init__(self) -> None:
        check_settings(self)
        self._check_statistical()
        self._check_filters()
        self._check_local()


@documented
@dataclass(frozen=True)
class PhotoSettings:
    """The photo check of the local modes (:func:`~roodi_toolkit.prune.photos.find_photos`)."""

    photos: str = setting("auto", "scene/object: keep what the posed photos show. auto: the training photos of the "
                          "model folder IN sits in (its cfg.json), if any; FOLDER: a model folder or a dataset "
                          "folder (COLMAP, NeRF-synthetic; decoded at 1/4 size); none: judge from the cloud alone.",
                          metavar="auto|none|FOLDER")
    photo_views: int = setting(32, "Render at most this many of the photos' views (evenly spaced).", low=1)

    def __post_init__(self) -> None:
        check_settings(self)


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
