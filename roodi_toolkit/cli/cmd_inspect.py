"""``roodi-toolkit inspect``: see a cloud in PyVista and what ``prune`` (same options, same default) would remove."""

from __future__ import annotations

import click
from matplotlib.colors import is_color_like

from roodi_toolkit.cli.common import overwrite_option, parse_size, quiet_option
from roodi_toolkit.cli.prune_options import (effective_mode, photo_inputs, photo_options, picture_title,
                                             prune_config_from_options, prune_mode_options, prune_options,
                                             prune_with_photos, write_floater_picture)
from roodi_toolkit.cli.settings import config_from_options, config_options
from roodi_toolkit.errors import ConfigError, EnvironmentProblemError
from roodi_toolkit.io.files import check_outputs, write_image
from roodi_toolkit.io.splat import input_paths, read_cloud
from roodi_toolkit.prune.config import PhotoSettings
from roodi_toolkit.prune.summary import summary_lines
from roodi_toolkit.render.upright import check_up, resolve_up
from roodi_toolkit.viz import inspect as insp
from roodi_toolkit.viz.inspect import InspectView
from roodi_toolkit.viz.page import floater_page, write_floater_page


EPILOG = """\b
Examples:
  roodi-toolkit inspect scene.ply --screenshot floaters.png         # the floater picture (as prune --dry-run)
  roodi-toolkit inspect scene.ply --html floaters.html              # a page to turn around in a browser
  roodi-toolkit inspect scene.ply                                   # a PyVista window (needs a display)
  roodi-toolkit inspect scene.ply --screenshot f.png --histogram hist.png
  roodi-toolkit inspect scene.ply --view-png view.png --show removed --camera +z --window-size 1600x1200
  roodi-toolkit inspect scene.ply --view-png d.png --color-by distance --rule paper --alpha 2   # the paper's rule
  roodi-toolkit inspect models/room/point_cloud/iteration_7000/point_cloud.ply --screenshot v.png   # photo check
"""

MAX_WINDOW = 4096
"""Largest --window-size side (a 4K screenshot fits; larger ones exceed common off-screen framebuffer limits)."""

@click.command(epilog=EPILOG)
@click.argument("input_ply", metavar="IN.ply", type=click.Path(path_type=str))
@prune_options
@prune_mode_options
@photo_options
@config_options(InspectView)
@click.option("--window-size", default="1024x768", show_default=True, metavar="WxH",
              help="Window and --view-png size in pixels.")
@click.option("--screenshot", type=click.Path(path_type=str), default=None,
              help="Write the floater picture (PNG, as prune --dry-run): three upright views, what stays in grey and "
                   "what goes in a colour per reason, renders before and after, counts per reason. No display needed.")
@click.option("--view-png", type=click.Path(path_type=str), default=None,
              help="Write a PNG of the PyVista view the window shows (--show, --color-by, --camera, --glyphs, "
                   "--highlight, --window-size), off screen.")
@click.option("--html", "html_path", type=click.Path(path_type=str), default=None,
              help="Write a self-contained web page to turn the cloud around (plotly): what stays in its colour, what "
                   "goes in a colour per reason, a legend with the counts.")
@click.option("--histogram", type=click.Path(path_type=str), default=None,
              help="Write the distribution of what the prune judged (blob scores, or the statistical rule's mean "
                   "neighbour distances on a log scale) with the threshold marked and the removed shaded.")
@click.option("--up", default=None, metavar="X,Y,Z|DATASET|auto",
              help="The cloud's up for the pictures, the page and the window (default auto: training cameras, the "
                   "format's convention, a ground plane, else z up; the one used is printed).")
@click.option("--window/--no-window", default=None,
              help="Open an interactive window. Default: only when a display exists and no file output is asked.")
@overwrite_option
@quiet_option
def inspect(input_ply: str, window_size: str, screenshot: str | None, view_png: str | None, html_path: str | None,
            histogram: str | None, up: str | None, window: bool | None, overwrite: bool, quiet: bool,
            **settings: object) -> None:
    """Show what `prune` with the same options would remove from IN (any readable splat format): by default its
    local tests and, for a trained model, the photo check.

    --screenshot writes the floater picture (the one prune --dry-run writes), --html a page to turn around, --view-png
    and the window the PyVista view, where each Gaussian is drawn with its footprint (oriented, scaled ellipsoids for
    small clouds, Gaussian splats sized by scale for large ones). Without a display, ask for a file.
    """
    config = prune_config_from_options(**{**settings, "mode": effective_mode(settings["mode"])})
    photo = config_from_options(PhotoSettings, settings)
    view = config_from_options(InspectView, settings)
    size = parse_size(window_size, "--window-size")
    if max(size) > MAX_WINDOW:  # VTK allocates the whole window off screen: 16384x16384 is 1 GiB per buffer
        raise click.BadParameter(f"at most {MAX_WINDOW}x{MAX_WINDOW} pixels, got {window_size!r}",
                                 param_hint="--window-size")
    named = [("--screenshot", screenshot), ("--view-png", view_png), ("--html", html_path), ("--histogram", histogram)]
    outputs = [p for _, p in named if p is not None]
    check_outputs(named, overwrite=overwrite,
                  inputs=[*input_paths(input_ply), *photo_inputs(input_ply, config.mode, photo.photos)])
    has_display = insp.display_available()
    if window is None:
        window = has_display and not outputs
    if window and not has_display:
        raise EnvironmentProblemError("no display to open a window on (DISPLAY is not set); use --screenshot, "
                                      "--html, --view-png or --histogram to write the view to files")
    if not window and not outputs:
        raise ConfigError("nothing to do: no display for a window and no output; pass --screenshot, --html, "
                          "--view-png or --histogram")
    highlight_colour = None if view.highlight.strip().lower() == "none" else view.highlight
    if highlight_colour is not None:
        if not is_color_like(highlight_colour):
            raise click.BadParameter(f"not a colour: {view.highlight!r} (use a name such as red or #ff00ff)",
                                     param_hint="--highlight")

    check_up(up)
    cloud = read_cloud(input_ply)
    _, keep, report = prune_with_photos(input_ply, cloud, config, photo, quiet)
    for line in summary_lines(report, dry_run=True):  # inspect prunes nothing: what would go
        click.echo(line)

    if histogram is not None:
        insp.save_histogram(insp.histogram_figure(report, keep=keep), histogram)
        click.echo(f"wrote {histogram}")
    if screenshot is None and html_path is None and view_png is None and not window:
        return
    up_axis = resolve_up(up, input_ply, cloud.means)
    click.echo(up_axis.describe())
    if screenshot is not None:
        write_floater_picture(input_ply, cloud, keep, report, screenshot, quiet, up=up)
        click.echo(f"wrote {screenshot}")
    if html_path is not None:
        write_floater_page(floater_page(cloud, keep, report, up_axis.vector, title=picture_title(input_ply),
                                        grey=view.color_by != "rgb"), html_path)
        click.echo(f"wrote {html_path}")
    if view_png is None and not window:
        return
    distances = insp.distances_per_gaussian(report, len(cloud)) if view.color_by == "distance" else None
    plotter = insp.plot_cloud(cloud, keep, show=view.show, color_by=view.color_by, distances=distances,
                              highlight=highlight_colour, glyphs=view.glyphs, camera=view.camera,
                              off_screen=not window, window_size=size, distance_label=insp.distance_label(report),
                              distance_log=insp.distance_is_log(report), up=up_axis.vector)
    try:
        if window:  # the PNG then shows the view the user left the window in
            plotter.show(title=f"roodi-toolkit inspect {input_ply}", auto_close=False)
        if view_png is not None:
            write_image(insp.screenshot_image(plotter), view_png)
            click.echo(f"wrote {view_png}")
    finally:
        plotter.close()
