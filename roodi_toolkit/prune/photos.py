"""The photos of the local prune's photo check: where they are, and loading them (the check itself:
:mod:`.photo_check`).

A flagged Gaussian that the training photos support stays.

The local tests of :mod:`.scene` judge a Gaussian by its neighbours alone. On a capture that misjudges real content:
a room's far wall, a table's edge or a chair seen by few photos is reconstructed by sparse Gaussians that fall apart
into small pieces, which the detached test takes for floaters (the statue's default model lost 11,701 of its 39,593
Gaussians and 2.9 dB against its held-out photos). When the photos the cloud was trained on are at hand, they settle
it: render each photo's view with every Gaussian and with the flagged ones left out, and ask, pixel by pixel, which
of the two is closer to the photo. The change of squared error ``delta(p)`` is shared among the flagged Gaussians in
proportion to their compositing weights at ``p``::

    support_i = sum over views and pixels p of  w_i(p) * delta(p),   delta(p) = err_without(p) - err_with(p)

(one rendering of the feature channel 1 and its gradient gives every ``support_i`` at once, with any renderer).
A flagged Gaussian whose removal makes the photos worse (``support_i > 0``) is kept; one the photos do not see
(``support_i = 0``) or that makes them worse (``support_i < 0``, a floater in front of what the photo shows) goes.
On datasets with alpha (RGBA renders such as NeRF-synthetic) the error is taken on both a black and a white
background, so the faint fog of a white training background counts against itself.

Sharing a pixel's change among all the flagged Gaussians there mixes what lies in front with what lies behind it: a
veil over a wall the photos show takes a share of the wall's support and stays, and the wall behind a floater takes
a share of the floater's harm and goes. The prune therefore calls this in two passes
(:func:`roodi_toolkit.prune.scene.prune_cloud`): the oversized blobs and fog first, then the detached pieces with
the blobs and fog that went left out.

Measured (``benchmarks/RESULTS.md``, "Prune on real splats"): the statue's held-out photos -2.89 dB without the
check, +0.00 dB with it; the default-trained lego -0.22 dB without, +0.00 dB with.

Photos come from the model folder the cloud sits in (its ``cfg.json`` names the data folder, the resolution and the
held-out views, which are never used), from a model folder or dataset folder given by ``--photos``, or not at all.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from ..cameras import spread_cameras
from ..errors import ConfigError, RoodiError
from ..io.files import read_json
from ..io.records import model_record
from ..progress import ProgressFactory, null_progress

if TYPE_CHECKING:  # torch and the renderer load only when there are photos: `prune` on a lone PLY never needs them
    import torch

    from ..cameras import Camera

PHOTO_VIEWS = 32
"""Views the check renders at most (spread round the scene by pose: :func:`~roodi_toolkit.cameras.spread_cameras`): on
the default-trained lego (87 training views) 32 evenly spaced views kept the same held-out figure as all 87 (-0.001 dB
against +0.001 dB) in 24 s instead of 74 s."""

DATASET_DOWNSCALE = 4.0
"""Resolution divisor for a dataset folder given directly (a model folder's record gives its own)."""

MATCH_RATIO = 0.5
"""The cloud must explain its photos: its squared error on them must be below this fraction of an empty
rendering's (3 dB better than the background alone), or the photos belong to another scene or frame."""

MODEL_SEARCH_DEPTH = 3
"""``auto`` looks for a model folder this many levels above the cloud (``MODEL/point_cloud/iteration_N/x.ply``)."""


class PhotosUnavailable(ConfigError):
    """A model folder's photos cannot be had here (the message says why)."""


@dataclass(frozen=True)
class Photos:
    """Posed photos to check a prune against.

    Attributes:
        images: ``[V, H, W, 3]`` float32, composited on ``background`` where the files had alpha.
        alphas: ``[V, H, W]`` the photos' alpha, or None.
        cameras: V cameras.
        background: RGB the photos were composited on.
        source: what they are, for messages (``"20 training views of DIR (downscale 4, from MODEL/cfg.json)"``).
    """

    images: "torch.Tensor"
    alphas: "torch.Tensor | None"
    cameras: Sequence["Camera"]
    background: tuple[float, float, float]
    source: str


def _from_dataset(path: Path, downscale: float, holdout_every: int, max_views: int, origin: str,
                  progress: ProgressFactory) -> Photos:
    from ..io.dataset import load_dataset, split_views  # lazy: the dataset readers import torch (photos only)

    dataset = load_dataset(path, downscale, progress=progress)
    train, _ = split_views(dataset, holdout_every)
    views = [train[i] for i in spread_cameras([dataset.cameras[v] for v in train], max_views)]  # by pose
    images = dataset.images[views]
    alphas = None if dataset.alphas is None else dataset.alphas[views]
    source = (f"{len(views)} of the {len(train)} training views of {path} (downscale {downscale:g}{origin})")
    return Photos(images, alphas, [dataset.cameras[i] for i in views], tuple(dataset.background), source)


def _is_model(folder: Path) -> bool:
    """Whether ``folder`` is a roodi-toolkit model folder (its record ``cfg.json`` beside ``point_cloud/``), or an
    Inria one (``cfg_args``)."""
    return ((folder / "cfg.json").is_file() or (folder / "cfg_args").is_file()) and (folder / "point_cloud").is_dir()


def _record(root: Path) -> tuple[dict, Path | None]:
    """Return a model folder's record and the data folder it names (relative names taken from the model folder
    when they exist there), or None for the data folder when it names none.

    Raises:
        InputError: ``cfg.json`` is not readable JSON.
    """
    if not (root / "cfg.json").is_file():  # an Inria folder: its cfg_args in this toolkit's keys
        return model_record(root)
    record = read_json(root / "cfg.json", "training record")
    record = record if isinstance(record, dict) else {}
    data_dir = record.get("data_dir")
    if not data_dir:
        return record, None
    data = Path(str(data_dir))
    return record, root / data if not data.is_absolute() and (root / data).exists() else data


def _model_photos(root: Path, max_views: int, progress: ProgressFactory) -> Photos:
    """Return the training photos named by the model folder's record.

    Raises:
        PhotosUnavailable: the record is unreadable or names no data folder, it is not on this machine, or it does
            not load.
    """
    where = root / "cfg.json" if (root / "cfg.json").is_file() else root / "cfg_args"
    try:
        record, data = _record(root)
    except RoodiError as exc:
        raise PhotosUnavailable(str(exc)) from None
    if data is None:
        raise PhotosUnavailable(f"{where} names no data folder")
    if not data.exists():
        raise PhotosUnavailable(f"the data folder {data} that {where} names is not here")
    if where.name == "cfg_args":  # an Inria model: its cameras.json must agree with the data's cameras
        from ..io.model import open_model  # lazy: the model reader imports the dataset readers (torch)

        try:
            open_model(root, data)
        except RoodiError as exc:
            raise PhotosUnavailable(str(exc)) from None
    downscale = float(record.get("downscale") or 1)
    holdout = int(record.get("holdout_every", 8))
    try:
        return _from_dataset(data, downscale, holdout, max_views, f", from {where}", progress)
    except RoodiError as exc:
        raise PhotosUnavailable(f"the data folder {data} that {where} names does not load: {exc}") from None


def _enclosing_model(cloud_path: Path) -> Path | None:
    """Return the roodi-toolkit model folder the cloud file sits in, if any."""
    try:
        folder = cloud_path.resolve().parent
    except (OSError, RuntimeError):  # a symbolic link loop: no model folder; reading the file says what is wrong
        return None
    for _ in range(MODEL_SEARCH_DEPTH):
        if _is_model(folder):
            return folder
        folder = folder.parent
    return None


def photo_folders(cloud_path: str | Path, spec: str = "auto") -> list[Path]:
    """Return the folders :func:`find_photos` would read for ``spec`` (the model folder and its data folder, or the
    folder given), without loading anything: inputs that no output may be written into."""
    if spec == "none":
        return []
    root = _enclosing_model(Path(cloud_path)) if spec == "auto" else Path(spec)
    if root is None or not root.is_dir():
        return []
    if not _is_model(root):
        return [root]
    try:
        _, data = _record(root)
    except RoodiError:
        return [root]
    return [root] + ([data] if data is not None and data.is_dir() else [])


def find_photos(cloud_path: str | Path, spec: str = "auto", *, max_views: int = PHOTO_VIEWS,
                downscale: float = DATASET_DOWNSCALE, progress: ProgressFactory = null_progress) -> Photos | None:
    """Return the photos to check a prune of ``cloud_path`` against, or None.

    Args:
        cloud_path: the cloud file being pruned.
        spec: ``auto`` (the training photos of the model folder the file sits in, if it sits in one), ``none``, or
            a folder: a model folder (its training photos, at its resolution) or a dataset folder (all its training
            views, at 1/``downscale`` size).
        max_views: render at most this many views (spread round the scene by pose).
        downscale: resolution divisor for a dataset folder (a model folder's record gives its own).
        progress: progress factory for loading.

    Raises:
        PhotosUnavailable: ``auto`` found a model folder whose photos cannot be had (not on this machine, not
            loadable); the caller may go on without them.
        ConfigError: ``spec`` is a path that is neither a model folder with its photos nor a dataset folder.
    """
    if spec == "none":
        return None
    if spec == "auto":
        root = _enclosing_model(Path(cloud_path))
        return None if root is None else _model_photos(root, max_views, progress)
    path = Path(spec)
    if not path.exists():
        raise ConfigError(f"--photos {spec}: no such folder (give a model folder, a dataset folder, auto or none)")
    if _is_model(path):
        try:
            return _model_photos(path, max_views, progress)
        except PhotosUnavailable as exc:
            raise ConfigError(f"--photos {spec}: {exc}") from None
    try:
        return _from_dataset(path, downscale, 0, max_views, "", progress)
    except RoodiError as exc:
        raise ConfigError(f"--photos {spec}: not a model folder, and not readable as a dataset ({exc})") from None
