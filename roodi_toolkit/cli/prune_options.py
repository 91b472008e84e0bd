"""The pruning options shared by ``prune``, ``inspect`` and ``batch prune``, made from the settings of
:mod:`roodi_toolkit.prune.config` (each declared once, in its field), so the commands prune the same way.

:func:`prune_options` adds the options of the neighbourhood, the statistical rule and the filters,
:func:`prune_mode_options` those of the mode and the local tests, :func:`photo_options` the photo check's (``prune`` and
``inspect``); :func:`prune_config_from_options` builds the :class:`~roodi_toolkit.prune.config.PruneConfig` of the
parsed values and :func:`prune_with_photos` runs :func:`~roodi_toolkit.prune.scene.prune_cloud` with them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from roodi_toolkit.cli.common import progress_factory, set_torch_threads
from roodi_toolkit.cli.settings import config_from_options, config_options, option_names
from roodi_toolkit.io.files import write_image
from roodi_toolkit.prune.config import (FilterSettings, LocalSettings, NeighbourSettings, PhotoSettings, PruneConfig,
                                        StatisticalSettings)
from roodi_toolkit.prune.photos import PhotosUnavailable, find_photos, photo_folders
from roodi_toolkit.prune.scene import prune_cloud
from roodi_toolkit.render.upright import resolve_up

prune_options = config_options(NeighbourSettings, StatisticalSettings, FilterSettings)
"""Decorator: the options of the neighbourhood (``--k``), the statistical rule and the filters."""

prune_mode_options = config_options(LocalSettings)
"""Decorator: ``--mode`` and the options of the local tests."""

photo_options = config_options(PhotoSettings)
"""Decorator: the photo check's options (``--photos``, ``--photo-views``)."""


def prune_config_from_options(**values: Any) -> PruneConfig:
    """Return the :class:`~roodi_toolkit.prune.config.PruneConfig` of a command's parsed pruning options (keyword
    names: the settings' fields; other keywords are ignored).

    Raises:
        ConfigError: values the config refuses (exit 1 with one line).
    """
    return config_from_options(PruneConfig, values)


def photo_inputs(input_path: str, mode: str, photos_spec: str) -> list[str]:
    """Return the folders the photo check would read for ``input_path`` (inputs no output may land in).

    Raises:
        click.BadParameter: a photo folder given with the statistical rule (it runs as published, without them).
    """

    if mode == "statistical":
        if photos_spec not in ("auto", "none"):
            raise click.BadParameter("the photo check belongs to the local tests (--mode auto, scene or object); "
                                     "the statistical rule runs as published", param_hint="--photos")
        return []
    return list(photo_folders(input_path, photos_spec))


PROGRESS_MIN_GAUSSIANS = 200_000
"""Clouds at least this large get progress bars while pruning (smaller ones finish in about a second)."""


def prune_with_photos(input_path: str, cloud: Any, config: PruneConfig, photo: PhotoSettings, quiet: bool, *,
                      select: bool = True) -> Any:
    """Return :func:`~roodi_toolkit.prune.scene.prune_cloud`'s result for ``cloud`` read from ``input_path``, with
    the photo check of ``photo`` (``--photos``, ``--photo-views``) in the local modes (a note on stderr when ``auto``
    finds none). Progress bars show for clouds of at least :data:`PROGRESS_MIN_GAUSSIANS`, and always for the photo
    check. ``select=False``: the result's cloud may be None (the keep mask says what stays)."""

    progress = progress_factory(quiet or len(cloud) < PROGRESS_MIN_GAUSSIANS)
    photos = None
    if config.mode != "statistical":
        if photo_folders(input_path, photo.photos):
            # the photo check is PyTorch work (loading and rendering the photos): on one thread unless --threads
            # says otherwise, as in every torch command (PyTorch's default of 2 OpenMP threads spin on a busy
            # machine: benchmarks/RESULTS.md, issue 33); a lone PLY never loads PyTorch
            set_torch_threads()
        try:
            photos = find_photos(input_path, photo.photos, max_views=photo.photo_views,
                                 progress=progress_factory(quiet))
        except PhotosUnavailable as exc:  # only --photos auto: the cloud alone still decides, as without a model
            click.echo(f"note: no photo check ({exc}); judging from the cloud alone", err=True)
    return prune_cloud(cloud, config, photos=photos, progress=progress_factory(quiet) if photos else progress,
                       select=select)


def effective_mode(mode: str) -> str:
    """Return the pruning mode a command runs: ``auto`` becomes ``statistical`` when the user gave an option of the
    statistical rule (--rule, --alpha, --distance, --neighbors) on the command line, since asking for them asks for
    that rule."""
    ctx = click.get_current_context()
    explicit = {name for name in option_names(StatisticalSettings)
                if name not in option_names(NeighbourSettings)
                and ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE}
    return "statistical" if mode == "auto" and explicit else mode


def picture_title(path: str, limit: int = 60) -> str:
    """Return how the floater picture names its input: the path as given, its tail when long; a SOG given as its
    ``meta.json`` or folder is named by the folder."""

    p = Path(path)
    text = str(p.parent) if p.name == "meta.json" else str(p)
    return text if len(text) <= limit else "..." + text[-(limit - 3):]


def write_floater_picture(input_path: str, cloud: Any, keep: Any, report: Any, path: str, quiet: bool, *,
                          up: str | None = None, dry_run: bool = True) -> Any:
    """Write the floater picture (:func:`roodi_toolkit.viz.floaters.floater_picture`) of a prune of ``cloud``, read
    from ``input_path``, upright on the cloud's up (``up``: ``--up``; :func:`roodi_toolkit.render.upright.resolve_up`);
    return that up axis (the caller says where it came from)."""
    from roodi_toolkit.viz.floaters import floater_picture  # lazy: matplotlib and the renderer, for a picture only

    set_torch_threads()  # the before/after renders
    axis = resolve_up(up, input_path, cloud.means)
    picture = floater_picture(cloud, keep, report, axis, title=picture_title(input_path), dry_run=dry_run,
                              progress=progress_factory(quiet))
    write_image(picture.image, path)
    return axis
