"""``roodi-toolkit inspect``: see a cloud in PyVista and what ``prune`` (same options, same default) would remove."""

from __future__ import annotations

import click

from roodi_toolkit.cli.common import overwrite_option, parse_size, quiet_option
from roodi_toolkit.cli.prune_options import (effective_mode, photo_inputs, photo_options,
                                             prune_config_from_options, prune_mode_options, prune_options,
                                             prune_with_photos)


EPILOG = """\b
Examples:
  roodi-toolkit inspect scene.ply                                   # a window (needs a display)
  roodi-toolkit inspect scene.ply --screenshot view.png --histogram hist.png
  roodi-toolkit inspect scene.ply --screenshot view.png --show removed --camera +z --window-size 1600x1200
  roodi-toolkit inspect scene.ply --screenshot d.png --color-by distance --rule paper --alpha 2   # the paper's rule
  roodi-toolkit inspect models/room/point_cloud/iteration_7000/point_cloud.ply --screenshot v.png   # photo check
  roodi-toolkit inspect scene.ply --html view.html                  # needs trame-pyvista
"""

MAX_WINDOW = 4096
"""Largest --window-size side (a 4K screenshot fits; larger ones exceed common off-screen framebuffer limits)."""

CAMERA_HELP = ("View direction: iso, xy (from +z), xz (from -y), yz (from +x), or the side the camera sits on: "
               "+x, -x, +y, -y, +z, -z. The camera frames the kept Gaussians.")


@click.command(epilog=EPILOG)
@click.argument("input_ply", metavar="IN.ply", type=click.Path(path_type=str))
@prune_options
@prune_mode_options
@photo_options
@click.option("--show", type=click.Choice(["both", "kept", "removed"]), default="both", show_default=True,
              help="Which Gaussians to draw.")
@click.option("--color-by", type=click.Choice(["rgb", "opacity", "scale", "distance"]), default="rgb",
              show_default=True,
              help="rgb: own colour (SH DC) with opacity as alpha; opacity, scale (largest axis) or distance (what "
                   "the prune judged: the blob score of the local tests, or the statistical rule's mean distance "
                   "to the K neighbours on a log colour bar) through a colour map.")
@click.option("--highlight", default="red", show_default=True, metavar="COLOR",
              help="Colour of the Gaussians pruning removes (a name or #rrggbb); 'none' draws them like the kept.")
@click.option("--glyphs", type=click.Choice(["auto", "ellipsoids", "splats"]), default="auto", show_default=True,
              help="ellipsoids: oriented, scaled ellipsoids (exact footprint, small clouds); splats: Gaussian point "
                   "splats sized by scale (fast); auto: ellipsoids up to 20,000 drawn Gaussians.")
@click.option("--camera", type=click.Choice(["iso", "xy", "xz", "yz", "+x", "-x", "+y", "-y", "+z", "-z"]),
              default="iso", show_default=True, help=CAMERA_HELP)
@click.option("--window-size", default="1024x768", show_default=True, metavar="WxH",
              help="Window and screenshot size in pixels.")
@click.option("--screenshot", type=click.Path(path_type=str), default=None,
              help="Write a PNG of the view (off screen; works without a display or GPU).")
@click.option("--html", "html_path", type=click.Path(path_type=str), default=None,
              help="Export an interactive HTML page (needs PyVista's trame extras).")
@click.option("--histogram", type=click.Path(path_type=str), default=None,
              help="Write the distribution of what the prune judged (blob scores, or the statistical rule's mean "
                   "neighbour distances on a log scale) with the threshold marked and the removed shaded.")
@click.option("--window/--no-window", default=None,
              help="Open an interactive window. Default: only when a display exists and no file output is asked.")
@overwrite_option
@quiet_option
def inspect(input_ply: str, show: str, color_by: str, highlight: str, glyphs: str, camera: str, window_size: str,
            screenshot: str | None, html_path: str | None, histogram: str | None, window: bool | None,
            overwrite: bool, quiet: bool, mode: str, photos_spec: str, photo_views: int,
            **prune_kwargs: object) -> None:
    """Show IN.ply (any readable splat format) in PyVista with the Gaussians that `prune` with the same options
    would remove highlighted: by default its local tests and, for a trained model, the photo check.

    Each Gaussian is drawn with its footprint: oriented, scaled ellipsoids for small clouds, Gaussian splats sized
    by scale for large ones. Without a display, ask for --screenshot, --html or --histogram.
    """
    from roodi_toolkit.viz import inspect as insp
    from roodi_toolkit.errors import ConfigError, EnvironmentProblemError
    from roodi_toolkit.io.files import check_outputs, write_image
    from roodi_toolkit.io.splat import input_paths, read_cloud

    mode = effective_mode(mode)
    config = prune_config_from_options(mode=mode, **prune_kwargs)
    size = parse_size(window_size, "--window-size")
    if max(size) > MAX_WINDOW:  # VTK allocates the whole window off screen: 16384x16384 is 1 GiB per buffer
        raise click.BadParameter(f"at most {MAX_WINDOW}x{MAX_WINDOW} pixels, got {window_size!r}",
                                 param_hint="--window-size")
    outputs = [p for p in (screenshot, html_path, histogram) if p is not None]
    check_outputs([("--screenshot", screenshot), ("--html", html_path), ("--histogram", histogram)],
                  overwrite=overwrite, inputs=[*input_paths(input_ply), *photo_inputs(input_ply, mode, photos_spec)])
    has_display = insp.display_available()
    if window is None:
        window = has_display and not outputs
    if window and not has_display:
        raise EnvironmentProblemError("no display to open a window on (DISPLAY is not set); use --screenshot, "
                                      "--html or --histogram to write the view to files")
    if not window and not outputs:
        raise ConfigError("nothing to do: no display for a window and no output; pass --screenshot, --html or "
                          "--histogram")
    if html_path is not None:  # refuse before the pruning, not after
        ok, reason = insp.html_export_supported()
        if not ok:
            raise EnvironmentProblemError(f"{html_path}: cannot export HTML: {reason}")
    highlight_colour = None if highlight.strip().lower() == "none" else highlight
    if highlight_colour is not None:
        import pyvista as pv

        try:
            pv.Color(highlight_colour)
        except ValueError:
            raise click.BadParameter(f"not a colour: {highlight!r} (use a name such as red or #ff00ff)",
                                     param_hint="--highlight") from None

    cloud = read_cloud(input_ply)
    _, keep, report = prune_with_photos(input_ply, cloud, config, photos_spec, photo_views, quiet)
    removed = ", ".join(f"{name} {n:,}" for name, n in report.stages if n) or "none"
    click.echo(f"mode {report.mode}: {report.mode_reason}")
    click.echo(f"kept {report.kept_count:,} of {report.input_count:,} Gaussians (removed: {removed}; "
               f"threshold {report.threshold:.6g})")

    if histogram is not None:
        insp.save_histogram(insp.histogram_figure(report, keep=keep), histogram)
        click.echo(f"wrote {histogram}")
    if screenshot is None and html_path is None and not window:
        return
    distances = insp.distances_per_gaussian(report, len(cloud)) if color_by == "distance" else None
    plotter = insp.plot_cloud(cloud, keep, show=show, color_by=color_by, distances=distances,
                              highlight=highlight_colour, glyphs=glyphs, camera=camera, off_screen=not window,
                              window_size=size, distance_label=insp.distance_label(report),
                              distance_log=insp.distance_is_log(report))
    try:
        if window:  # the files then show the view the user left the window in
            plotter.show(title=f"roodi-toolkit inspect {input_ply}", auto_close=False)
        if html_path is not None:
            insp.export_html(plotter, html_path)
            click.echo(f"wrote {html_path}")
        if screenshot is not None:
            write_image(insp.screenshot_image(plotter), screenshot)
            click.echo(f"wrote {screenshot}")
    finally:
        plotter.close()
