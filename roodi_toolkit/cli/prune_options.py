"""The pruning options shared by ``prune``, ``inspect`` and ``batch``: one definition, so the commands prune the same
way (``tests/viz/test_inspect.py`` checks that ``prune`` and ``inspect`` offer the same options).

:func:`prune_options` adds the statistical rule's options and the filters, :func:`prune_mode_options` the modes
(``--mode``, the local tests, ``--filter-value``), :func:`photo_options` the photo check (``prune`` and ``inspect``);
:func:`prune_config_from_options` turns them into a :class:`~roodi_toolkit.prune.config.PruneConfig` and
:func:`prune_with_photos` runs :func:`~roodi_toolkit.prune.scene.prune_cloud` with them.
"""

from __future__ import annotations

from typing import Any, Callable, TypeVar

import click

from roodi_toolkit.cli.common import parse_floats

F = TypeVar("F", bound=Callable[..., Any])

PRUNE_OPTION_NAMES = ("k", "alpha", "distance", "rule", "neighbors", "filter_nan", "min_opacity", "filter_box",
                      "filter_sphere")
"""Keyword names a command decorated with :func:`prune_options` receives."""

_OPTIONS = [
    click.option("--k", "k", type=click.IntRange(min=1), default=16, show_default=True,
                 help="Neighbours per Gaussian, not counting itself."),
    click.option("--alpha", type=click.FloatRange(min=0, min_open=True), default=None,
                 help="Threshold multiplier. Default per rule: robust 3.5, paper 2, clip 3."),
    click.option("--distance", type=click.Choice(["w2", "euclidean"]), default="w2", show_default=True,
                 help="w2: squared 2-Wasserstein between Gaussians (paper); euclidean: plain centre distance "
                      "(Open3D)."),
    click.option("--rule", type=click.Choice(["robust", "paper", "clip"]), default="robust", show_default=True,
                 help="robust: median/MAD of log distances, re-evaluated without flagged neighbours; paper: one pass "
                      "of mean + alpha * std; clip: iterated mean + alpha * std."),
    click.option("--neighbors", type=click.Choice(["centre", "w2"]), default="centre", show_default=True,
                 help="centre: K nearest centres (paper); w2: exact K nearest under W2 (slower)."),
    click.option("--filter-nan", is_flag=True,
                 help="Drop Gaussians with NaN/Inf values (otherwise they are an error)."),
    click.option("--min-opacity", type=click.FloatRange(0, 1, max_open=True), default=None,
                 help="Drop Gaussians whose opacity (linear, after sigmoid) is below this, e.g. 0.0039 = 1/255."),
    click.option("--filter-box", metavar="X0,Y0,Z0,X1,Y1,Z1", default=None,
                 help="Keep only Gaussians whose centre is inside this axis-aligned box."),
    click.option("--filter-sphere", metavar="X,Y,Z,R", default=None,
                 help="Keep only Gaussians whose centre is inside this sphere."),
]


_MODE_OPTIONS = [
    click.option("--mode", type=click.Choice(["auto", "scene", "object", "statistical"]), default="auto",
                 show_default=True,
                 help="scene: remove pieces detached from the content and oversized blobs, judged locally (safe on "
                      "real scenes); object: one object, what is detached from it goes (see --max-piece); "
                      "statistical: the global rule of --rule (paper: ROODI 3.2 as published); auto: object or "
                      "scene, the choice is printed and reported. Giving --rule, --alpha, --distance or --neighbors "
                      "with auto implies statistical."),
    click.option("--reach", type=click.FloatRange(min=0, min_open=True), default=1.5, show_default=True,
                 help="scene/object: two Gaussians are connected when their centres are closer than this many sums "
                      "of their largest scales."),
    click.option("--min-cluster", type=click.FloatRange(0, 1, max_open=True), default=0.001, show_default=True,
                 help="scene: remove connected pieces with fewer than this fraction of the Gaussians."),
    click.option("--max-piece", type=click.IntRange(min=0), default=3, show_default=True,
                 help="scene/object without photos: a detached piece goes only when it holds at most this many "
                      "Gaussians (larger ones are often real content split off); 0: any size. With photos every "
                      "detached piece is put to them."),
    click.option("--blob-score", type=float, default=0.5, show_default=True,
                 help="scene/object: remove Gaussians whose smallest axis exceeds the local spacing and size by "
                      "more than this (log units; higher keeps more)."),
    click.option("--blob-colour", type=click.FloatRange(min=0), default=0.12, show_default=True,
                 help="scene/object without photos: an oversized Gaussian stays when one of its neighbours has "
                      "its base colour within this RGB distance (0-1 units) and it scores at most --blob-sure; 0: "
                      "colour is not asked. With photos every oversized Gaussian is put to them."),
    click.option("--blob-sure", type=float, default=2.0, show_default=True,
                 help="scene/object without photos: oversized Gaussians scoring above this go whatever their "
                      "colour."),
    click.option("--foreign-size", type=click.FloatRange(min=0), default=6.0, show_default=True,
                 help="scene/object: a round Gaussian whose smallest axis is over this many times the scene's "
                      "median Gaussian size (and over its neighbours' median size), with a colour none of its "
                      "neighbours has, is oversized whatever its score (a blob among large Gaussians); 0: off. "
                      "With photos it is put to them."),
    click.option("--background", type=click.Choice(["auto", "white", "black", "none"]), default="auto",
                 show_default=True,
                 help="scene/object: the solid background the scene was trained on; its colour's faint fog goes. "
                      "auto: detected (a wide, faint cloud of exactly white or black Gaussians)."),
    click.option("--filter-value", "filter_values", metavar="NAME,MIN,MAX", multiple=True,
                 help="Keep only Gaussians with NAME in [MIN, MAX]; NAME is x, y, z, opacity (linear), scale "
                      "(largest axis) or min_scale. Repeatable."),
]

MODE_OPTION_NAMES = ("mode", "reach", "min_cluster", "max_piece", "blob_score", "blob_colour", "blob_sure",
                     "foreign_size", "background", "filter_values")
"""Keyword names a command decorated with :func:`prune_mode_options` receives."""


def prune_mode_options(func: F) -> F:
    """Return ``func`` decorated with the mode options (auto/scene/object/statistical, the local tests' settings, value
    filters)."""
    for option in reversed(_MODE_OPTIONS):
        func = option(func)
    return func


_PHOTO_OPTIONS = [
    click.option("--photos", "photos_spec", default="auto", show_default=True, metavar="auto|none|FOLDER",
                 help="scene/object: keep what the posed photos show. auto: the training photos of the model folder "
                      "IN sits in (its cfg.json), if any; FOLDER: a model folder or a dataset folder (COLMAP, "
                      "NeRF-synthetic; decoded at 1/4 size); none: judge from the cloud alone."),
    click.option("--photo-views", type=click.IntRange(min=1), default=32, show_default=True,
                 help="Render at most this many of the photos' views (evenly spaced)."),
]


def photo_options(func: F) -> F:
    """Return ``func`` decorated with the photo check's options (``photos_spec``, ``photo_views``)."""
    for option in reversed(_PHOTO_OPTIONS):
        func = option(func)
    return func


def photo_inputs(input_path: str, mode: str, photos_spec: str) -> list[str]:
    """Return the folders the photo check would read for ``input_path`` (inputs no output may land in).

    Raises:
        click.BadParameter: a photo folder given with the statistical rule (it runs as published, without them).
    """
    from roodi_toolkit.prune.photos import photo_folders

    if mode == "statistical":
        if photos_spec not in ("auto", "none"):
            raise click.BadParameter("the photo check belongs to the local tests (--mode auto, scene or object); "
                                     "the statistical rule runs as published", param_hint="--photos")
        return []
    return list(photo_folders(input_path, photos_spec))


PROGRESS_MIN_GAUSSIANS = 200_000
"""Clouds at least this large get progress bars while pruning (smaller ones finish in about a second)."""


def prune_with_photos(input_path: str, cloud: Any, config: Any, photos_spec: str, photo_views: int,
                      quiet: bool, *, select: bool = True) -> Any:
    """Return :func:`~roodi_toolkit.prune.scene.prune_cloud`'s result for ``cloud`` read from ``input_path``, with
    the photo check of ``--photos`` in the local modes (a note on stderr when ``auto`` finds none). Progress bars
    show for clouds of at least :data:`PROGRESS_MIN_GAUSSIANS`, and always for the photo check. ``select=False``:
    the result's cloud may be None (the keep mask says what stays)."""
    from roodi_toolkit.cli.common import progress_factory, set_torch_threads
    from roodi_toolkit.prune.photos import PhotosUnavailable, find_photos, photo_folders
    from roodi_toolkit.prune.scene import prune_cloud

    progress = progress_factory(quiet or len(cloud) < PROGRESS_MIN_GAUSSIANS)
    photos = None
    if config.mode != "statistical":
        if photo_folders(input_path, photos_spec):
            # the photo check is PyTorch work (loading and rendering the photos): on one thread unless --threads
            # says otherwise, as in every torch command (PyTorch's default of 2 OpenMP threads spin on a busy
            # machine: benchmarks/RESULTS.md, issue 33); a lone PLY never loads PyTorch
            set_torch_threads()
        try:
            photos = find_photos(input_path, photos_spec, max_views=photo_views, progress=progress_factory(quiet))
        except PhotosUnavailable as exc:  # only --photos auto: the cloud alone still decides, as without a model
            click.echo(f"note: no photo check ({exc}); judging from the cloud alone", err=True)
    return prune_cloud(cloud, config, photos=photos, progress=progress_factory(quiet) if photos else progress,
                       select=select)


def parse_value_ranges(values: tuple[str, ...]) -> tuple[tuple[str, float, float], ...]:
    """Return ``((name, low, high), ...)`` from ``--filter-value NAME,MIN,MAX`` options.

    Raises:
        click.BadParameter: a malformed entry.
    """
    from roodi_toolkit.prune.outliers import VALUE_NAMES

    out = []
    for text in values:
        name, _, rest = text.partition(",")
        if name not in VALUE_NAMES:
            raise click.BadParameter(f"{text!r}: NAME must be one of {', '.join(VALUE_NAMES)}",
                                     param_hint="--filter-value")
        low, high = parse_floats(rest, 2, "--filter-value")
        if not low <= high:
            raise click.BadParameter(f"{text!r}: MIN must not exceed MAX", param_hint="--filter-value")
        out.append((name, float(low), float(high)))
    return tuple(out)


def prune_options(func: F) -> F:
    """Return ``func`` decorated with the pruning options, in the order ``prune --help`` lists them."""
    for option in reversed(_OPTIONS):
        func = option(func)
    return func


def prune_config_from_options(*, k: int, alpha: float | None, distance: str, rule: str, neighbors: str,
                              filter_nan: bool, min_opacity: float | None, filter_box: str | None,
                              filter_sphere: str | None, mode: str = "auto", reach: float = 1.5,
                              min_cluster: float = 0.001, max_piece: int = 3, blob_score: float = 0.5,
                              blob_colour: float = 0.12, blob_sure: float = 2.0, foreign_size: float = 6.0,
                              background: str = "auto", filter_values: tuple[str, ...] = ()) -> Any:
    """Return the ``PruneConfig`` the pruning options describe.

    Raises:
        click.BadParameter: a malformed ``--filter-box`` or ``--filter-sphere`` (usage error, exit 2).
        ConfigError: values :class:`~roodi_toolkit.prune.config.PruneConfig` refuses (exit 1 with one line).
    """
    from roodi_toolkit.prune.outliers import PruneConfig

    box = parse_floats(filter_box, 6, "--filter-box") if filter_box is not None else None
    sphere = parse_floats(filter_sphere, 4, "--filter-sphere") if filter_sphere is not None else None
    return PruneConfig(k=k, alpha=alpha, distance=distance, rule=rule, neighbors=neighbors, filter_nan=filter_nan,
                       min_opacity=min_opacity, box=box, sphere=sphere, mode=mode, reach=reach,
                       min_cluster=min_cluster, max_piece=max_piece, blob_score=blob_score,
                       blob_colour=blob_colour, blob_sure=blob_sure, foreign_size=foreign_size,
                       background=background, value_ranges=parse_value_ranges(filter_values))


def effective_mode(mode: str) -> str:
    """Return the pruning mode a command runs: ``auto`` becomes ``statistical`` when the user gave an option of the
    statistical rule (--rule, --alpha, --distance, --neighbors) on the command line, since asking for them asks for
    that rule."""
    ctx = click.get_current_context()
    explicit = {name for name in ("rule", "alpha", "distance", "neighbors")
                if ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE}
    return "statistical" if mode == "auto" and explicit else mode


def picture_title(path: str, limit: int = 60) -> str:
    """Return how the floater picture names its input: the path as given, its tail when long; a SOG given as its
    ``meta.json`` or folder is named by the folder."""
    from pathlib import Path

    p = Path(path)
    text = str(p.parent) if p.name == "meta.json" else str(p)
    return text if len(text) <= limit else "..." + text[-(limit - 3):]


def write_floater_picture(input_path: str, cloud: Any, keep: Any, report: Any, path: str, quiet: bool, *,
                          up: str | None = None, dry_run: bool = True) -> Any:
    """Write the floater picture (:func:`roodi_toolkit.viz.floaters.floater_picture`) of a prune of ``cloud``, read
    from ``input_path``, upright on the cloud's up (``up``: ``--up``; :func:`roodi_toolkit.render.upright.resolve_up`);
    return that up axis (the caller says where it came from)."""
    from roodi_toolkit.cli.common import progress_factory, set_torch_threads
    from roodi_toolkit.io.files import write_image
    from roodi_toolkit.render.upright import resolve_up
    from roodi_toolkit.viz.floaters import floater_picture

    set_torch_threads()  # the before/after renders
    axis = resolve_up(up, input_path, cloud.means)
    picture = floater_picture(cloud, keep, report, axis, title=picture_title(input_path), dry_run=dry_run,
                              progress=progress_factory(quiet))
    write_image(picture.image, path)
    return axis
