"""``roodi-toolkit prune``: remove floaters from a 3DGS PLY (local scene/object tests by default; ROODI section 3.2's
statistical rule with ``--mode statistical``)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import click

from roodi_toolkit.cli.common import overwrite_option, quiet_option
from roodi_toolkit.cli.prune_options import (effective_mode, photo_inputs, photo_options, prune_config_from_options,
                                             prune_mode_options, prune_options, prune_with_photos,
                                             write_floater_picture)
from roodi_toolkit.cli.settings import config_from_options
from roodi_toolkit.io.files import check_outputs, write_json
from roodi_toolkit.io.splat import WRITE_SUFFIXES, input_paths, read_cloud, write_cloud
from roodi_toolkit.prune.config import PhotoSettings
from roodi_toolkit.prune.summary import summary_lines
from roodi_toolkit.render.upright import check_up


EPILOG = """\b
Examples:
  roodi-toolkit prune scene.ply clean.ply
  roodi-toolkit prune scene.ply clean.ply --floaters-out floaters.ply --report prune.json
  roodi-toolkit prune scene.ply clean.ply --dry-run                  # clean.prune.json + clean.prune.png only
  roodi-toolkit prune scene.ply clean.ply --mode object              # one object: what is detached goes
  roodi-toolkit prune models/room/point_cloud/iteration_7000/point_cloud.ply clean.ply   # checked against its photos
  roodi-toolkit prune other_tool.ply clean.ply --photos ../captures/room   # a dataset folder: its photos
  roodi-toolkit prune scene.ply clean.ply --mode statistical --rule paper --alpha 2 --k 16   # the paper's rule
  roodi-toolkit prune scene.ply clean.ply --filter-nan --min-opacity 0.004 --filter-sphere 0,0,0,3
  roodi-toolkit prune scene.ply clean.ply --filter-value scale,0,0.5 --filter-value z,-1,10
"""


@click.command(epilog=EPILOG)
@click.argument("input_ply", metavar="IN", type=click.Path(path_type=str))
@click.argument("output_ply", metavar="OUT", type=click.Path(path_type=str))
@prune_options
@prune_mode_options
@photo_options
@click.option("--dry-run", is_flag=True,
              help="Write no cloud: only the report (--report, default OUT's name + .prune.json) and the floater "
                   "picture (OUT's name + .prune.png): three upright views with what stays in grey and what would go "
                   "in a colour per reason, renders before and after, counts per reason.")
@click.option("--up", default=None, metavar="X,Y,Z|DATASET|auto",
              help="The cloud's up for the --dry-run picture (default auto: training cameras, the format's "
                   "convention, a ground plane, else z up; the one used is printed).")
@click.option("--floaters-out", type=click.Path(path_type=str), default=None,
              help="Also write the removed Gaussians to this PLY.")
@click.option("--report", "report_path", type=click.Path(path_type=str), default=None,
              help="Write counts per stage, thresholds and timings as JSON.")
@overwrite_option
@quiet_option
def prune(input_ply: str, output_ply: str, dry_run: bool, up: str | None, floaters_out: str | None,
          report_path: str | None, overwrite: bool, quiet: bool, **settings: object) -> None:
    """Remove floaters from IN (any readable splat format) and write the kept Gaussians to OUT (.ply,
    .compressed.ply or .spz, from its extension).

    Every column of the input, extra properties included, is kept for the kept Gaussians, in input order.
    The filters (--filter-nan, --min-opacity, --filter-box, --filter-sphere, --filter-value) run first.
    """
    start = time.perf_counter()
    _skip_hugepage_advice()
    config = prune_config_from_options(**{**settings, "mode": effective_mode(settings["mode"])})
    photo = config_from_options(PhotoSettings, settings)
    photo_folders = photo_inputs(input_ply, config.mode, photo.photos)
    if up is not None and not dry_run:
        raise click.BadParameter("--up sets the --dry-run picture's up; the pruned cloud keeps its axes",
                                 param_hint="--up")
    check_up(up)
    picture = None
    if dry_run:
        stem = Path(output_ply)
        suffix = next((s for s in WRITE_SUFFIXES if stem.name.lower().endswith(s)), "")
        stem = stem.with_name(stem.name[:len(stem.name) - len(suffix)])
        picture = f"{stem}.prune.png"
        report_path = report_path or f"{stem}.prune.json"
        if floaters_out is not None:
            raise click.BadParameter("--dry-run writes no cloud; leave out --floaters-out",
                                     param_hint="--floaters-out")
    check_outputs([("OUT", None if dry_run else output_ply), ("--floaters-out", floaters_out),
                   ("--report", report_path), ("the dry run's picture", picture)], overwrite=overwrite,
                  inputs=[*input_paths(input_ply), *photo_folders])

    t_read = time.perf_counter()
    cloud = read_cloud(input_ply)
    read_s = time.perf_counter() - t_read
    # the kept Gaussians are gathered while writing (no copy of the pruned cloud first)
    _, keep, report = prune_with_photos(input_ply, cloud, config, photo, quiet, select=False)

    t_write = time.perf_counter()
    up_axis = None
    if dry_run:
        up_axis = write_floater_picture(input_ply, cloud, keep, report, picture, quiet, up=up)
    else:
        write_cloud(cloud, output_ply, rows=None if keep.all() else keep)
    floaters_written = floaters_out is not None and not keep.all()
    if floaters_written:
        write_cloud(cloud.select(~keep), floaters_out)
    report.timings["read"] = read_s
    report.timings["write"] = time.perf_counter() - t_write
    report.timings["command_total"] = time.perf_counter() - start
    if report_path is not None:
        summary = report.to_dict()
        summary["input"], summary["output"] = input_ply, None if dry_run else output_ply
        summary["dry_run"], summary["picture"] = dry_run, picture
        summary["floaters_output"] = floaters_out if floaters_written else None
        if up_axis is not None:
            summary["picture_up"] = {"up": up_axis.vector.tolist(), "from": up_axis.source}
        write_json(summary, report_path)
    for line in summary_lines(report, dry_run=dry_run):
        click.echo(line)
    if up_axis is not None:
        click.echo(f"picture {up_axis.describe()}")
    wrote = [picture, report_path] if dry_run else [output_ply, floaters_out if floaters_written else None,
                                                    report_path]
    click.echo(f"wrote {', '.join(p for p in wrote if p)}")
    if floaters_out is not None and not floaters_written:
        click.echo(f"nothing was removed, so no floater PLY was written to {floaters_out}")


def _skip_hugepage_advice() -> None:
    """Stop NumPy from advising the kernel to back new arrays with transparent huge pages, as
    ``NUMPY_MADVISE_HUGEPAGE=0`` does (a value the user set in the environment wins).

    The prune touches several fresh ``[N, K]`` arrays once each. Where the kernel compacts memory to serve huge
    pages at the first touch (THP defrag ``madvise``, a common default), those faults cost more than the pages
    save: on the 2-core machine the command on 1.07M Gaussians took 8.6-9.5 s instead of 9.8-10.8 s, system time
    0.6 s instead of 1.2-1.3 s (``benchmarks/RESULTS.md``, "Prune on real splats"). NumPy offers the switch after
    import only privately; without it nothing changes.
    """
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return
    try:
        from numpy._core.multiarray import _set_madvise_hugepage  # lazy: private to NumPy 2; other layouts lack it
    except ImportError:  # another NumPy layout: keep its default
        return
    _set_madvise_hugepage(False)
