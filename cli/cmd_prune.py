"""``roodi-toolkit prune``: remove floaters from a 3DGS PLY by statistical outlier removal (ROODI section 3.2)."""

from __future__ import annotations

import click

from roodi_toolkit.cli.common import overwrite_option, parse_floats, progress_factory, quiet_option

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
@click.option("--k", "k", type=click.IntRange(min=1), default=16, show_default=True,
              help="Neighbours per Gaussian, not counting itself.")
@click.option("--alpha", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Threshold multiplier. Default per rule: robust 3.5, paper 2, clip 3.")
@click.option("--distance", type=click.Choice(["w2", "euclidean"]), default="w2", show_default=True,
              help="w2: squared 2-Wasserstein between Gaussians (paper); euclidean: plain centre distance (Open3D).")
@click.option("--rule", type=click.Choice(["robust", "paper", "clip"]), default="robust", show_default=True,
              help="robust: median/MAD of log distances, re-evaluated without flagged neighbours; paper: one pass "
                   "of mean + alpha * std; clip: iterated mean + alpha * std.")
@click.option("--neighbors", type=click.Choice(["centre", "w2"]), default="centre", show_default=True,
              help="centre: K nearest centres (paper); w2: exact K nearest under W2 (slower).")
@click.option("--filter-nan", is_flag=True, help="Drop Gaussians with NaN/Inf values (otherwise they are an error).")
@click.option("--min-opacity", type=click.FloatRange(0, 1, max_open=True), default=None,
              help="Drop Gaussians whose opacity (linear, after sigmoid) is below this, e.g. 0.0039 = 1/255.")
@click.option("--filter-box", metavar="X0,Y0,Z0,X1,Y1,Z1", default=None,
              help="Keep only Gaussians whose centre is inside this axis-aligned box.")
@click.option("--filter-sphere", metavar="X,Y,Z,R", default=None,
              help="Keep only Gaussians whose centre is inside this sphere.")
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
    from roodi_toolkit.files import check_output, write_json
    from roodi_toolkit.outliers import PruneConfig, remove_statistical_outliers
    from roodi_toolkit.ply import read_ply, write_ply

    start = time.perf_counter()
    box = parse_floats(filter_box, 6, "--filter-box") if filter_box is not None else None
    sphere = parse_floats(filter_sphere, 4, "--filter-sphere") if filter_sphere is not None else None
    config = PruneConfig(k=k, alpha=alpha, distance=distance, rule=rule, neighbors=neighbors, filter_nan=filter_nan,
                         min_opacity=min_opacity, box=box, sphere=sphere)
    outputs = [p for p in (output_ply, floaters_out, report_path) if p is not None]
    for path in outputs:
        check_output(path, overwrite=overwrite, inputs=[input_ply])
    if len({str(click.format_filename(p)) for p in outputs}) != len(outputs):
        raise OutputError("OUT.ply, --floaters-out and --report must be different files")

    t_read = time.perf_counter()
    cloud = read_ply(input_ply)
    read_s = time.perf_counter() - t_read
    progress = progress_factory(quiet or len(cloud) < PROGRESS_MIN_GAUSSIANS)
    pruned, keep, report = remove_statistical_outliers(cloud, config, progress=progress)

    t_write = time.perf_counter()
    write_ply(pruned, output_ply)
    if floaters_out is not None:
        if keep.all():
            raise OutputError(f"{floaters_out}: nothing was removed, so there is no floater PLY to write "
                              f"({output_ply} was written)")
        write_ply(cloud.select(~keep), floaters_out)
    report.timings["read"] = read_s
    report.timings["write"] = time.perf_counter() - t_write
    report.timings["command_total"] = time.perf_counter() - start
    if report_path is not None:
        summary = report.to_dict()
        summary["input"], summary["output"], summary["floaters_output"] = input_ply, output_ply, floaters_out
        write_json(summary, report_path)
    removed = ", ".join(f"{name} {n:,}" for name, n in report.stages if n) or "none"
    click.echo(f"kept {report.kept_count:,} of {report.input_count:,} Gaussians (removed: {removed}; "
               f"threshold {report.threshold:.4g}); wrote {output_ply}")
