"""``roodi-toolkit prune``: remove floaters from a 3DGS PLY by statistical outlier removal (ROODI section 3.2)."""

from __future__ import annotations

import click

from roodi_toolkit.cli.common import overwrite_option, progress_factory, quiet_option
from roodi_toolkit.cli.prune_options import prune_config_from_options, prune_options

PROGRESS_MIN_GAUSSIANS = 200_000
"""Clouds at least this large get progress bars (smaller ones finish in about a second)."""

EPILOG = """\b
Examples:
  roodi-toolkit prune scene.ply clean.ply
  roodi-toolkit prune scene.ply clean.ply --floaters-out floaters.ply --report prune.json
  roodi-toolkit prune scene.ply clean.ply --rule paper --alpha 2 --k 16
  roodi-toolkit prune scene.ply clean.ply --distance euclidean      # Open3D-style centre distances
  roodi-toolkit prune scene.ply clean.ply --filter-nan --min-opacity 0.004 --filter-sphere 0,0,0,3
"""


@click.command(epilog=EPILOG)
@click.argument("input_ply", metavar="IN.ply", type=click.Path(path_type=str))
@click.argument("output_ply", metavar="OUT.ply", type=click.Path(path_type=str))
@prune_options
@click.option("--floaters-out", type=click.Path(path_type=str), default=None,
              help="Also write the removed Gaussians to this PLY.")
@click.option("--report", "report_path", type=click.Path(path_type=str), default=None,
              help="Write counts per stage, thresholds and timings as JSON.")
@overwrite_option
@quiet_option
def prune(input_ply: str, output_ply: str, k: int, alpha: float | None, distance: str, rule: str, neighbors: str,
          filter_nan: bool, min_opacity: float | None, filter_box: str | None, filter_sphere: str | None,
          floaters_out: str | None, report_path: str | None, overwrite: bool, quiet: bool) -> None:
    """Remove floaters from IN.ply and write the kept Gaussians to OUT.ply.

    Every column of the input, extra properties included, is kept for the kept Gaussians, in input order.
    The filters (--filter-nan, --min-opacity, --filter-box, --filter-sphere) run before the statistics.
    """
    import time

    from roodi_toolkit.errors import OutputError
    from roodi_toolkit.io.files import check_output, write_json
    from roodi_toolkit.prune.outliers import remove_statistical_outliers
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.io.splat import read_cloud

    start = time.perf_counter()
    config = prune_config_from_options(k=k, alpha=alpha, distance=distance, rule=rule, neighbors=neighbors,
                                       filter_nan=filter_nan, min_opacity=min_opacity, filter_box=filter_box,
                                       filter_sphere=filter_sphere)
    outputs = [p for p in (output_ply, floaters_out, report_path) if p is not None]
    for path in outputs:
        check_output(path, overwrite=overwrite, inputs=[input_ply])
    if len({str(click.format_filename(p)) for p in outputs}) != len(outputs):
        raise OutputError("OUT.ply, --floaters-out and --report must be different files")

    t_read = time.perf_counter()
    cloud = read_cloud(input_ply)
    read_s = time.perf_counter() - t_read
    progress = progress_factory(quiet or len(cloud) < PROGRESS_MIN_GAUSSIANS)
    pruned, keep, report = remove_statistical_outliers(cloud, config, progress=progress)

    t_write = time.perf_counter()
    write_ply(pruned, output_ply)
    floaters_written = floaters_out is not None and not keep.all()
    if floaters_written:
        write_ply(cloud.select(~keep), floaters_out)
    report.timings["read"] = read_s
    report.timings["write"] = time.perf_counter() - t_write
    report.timings["command_total"] = time.perf_counter() - start
    if report_path is not None:
        summary = report.to_dict()
        summary["input"], summary["output"] = input_ply, output_ply
        summary["floaters_output"] = floaters_out if floaters_written else None
        write_json(summary, report_path)
    removed = ", ".join(f"{name} {n:,}" for name, n in report.stages if n) or "none"
    click.echo(f"kept {report.kept_count:,} of {report.input_count:,} Gaussians (removed: {removed}; "
               f"threshold {report.threshold:.4g}); wrote {output_ply}")
    if floaters_out is not None and not floaters_written:
        click.echo(f"nothing was removed, so no floater PLY was written to {floaters_out}")
