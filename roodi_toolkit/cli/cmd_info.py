"""``roodi-toolkit info``: what is in a splat file (any readable format)."""

from __future__ import annotations

import os

import click

from roodi_toolkit.io.files import json_text
from roodi_toolkit.io.ply import ply_info
from roodi_toolkit.io.splat import OPACITY_LOGIT_LIMIT, read_cloud_report
from roodi_toolkit.stats import describe_cloud


def _fmt(x: float) -> str:
    return f"{x:.4g}"


@click.command(epilog="Example:\n\n\b\n  roodi-toolkit info scene.ply\n  roodi-toolkit info scene.ply --json > info.json")
@click.argument("ply", metavar="FILE", type=click.Path(dir_okay=True, path_type=str))
@click.option("--json", "as_json", is_flag=True,
              help="Print machine-readable JSON instead of a table (NaN and infinite values as null).")
def info(ply: str, as_json: bool) -> None:
    """Show the detected format, count, SH degree, bounding box, opacity and scale statistics and bad values of FILE.

    FILE is any readable splat: PLY, compressed PLY, SPZ, SOG (.sog, meta.json or its folder), .splat, .ksplat.
    """
    cloud, report = read_cloud_report(ply)
    stats = describe_cloud(cloud)
    bad = stats["bad_values"]
    bad["opacity_pos_inf"], bad["opacity_neg_inf"] = report.opacity_pos_inf, report.opacity_neg_inf
    file_info = {"path": report.path, "format": report.format, "bytes": os.path.getsize(report.path)}
    if report.format == "ply":
        layout = ply_info(report.path)
        file_info.update(encoding=layout.format, variant=layout.variant, properties=len(layout.property_names))
    stats["file"] = file_info
    if as_json:
        click.echo(json_text(stats, indent=2))  # strict JSON: NaN and infinities as null
        return
    bb = stats["bbox"]
    op = stats["opacity"]
    smax, smin = stats["scale_max_axis"], stats["scale_min_axis"]
    detail = (f"{file_info['variant']} {file_info['encoding']}, {file_info['properties']} properties, "
              if report.format == "ply" else "")
    lines = [
        f"file            {report.path}",
        f"format          {report.format} ({detail}{file_info['bytes']:,} bytes)",
        f"gaussians       {stats['count']:,}",
        f"sh degree       {stats['sh_degree']}",
    ]
    if bb["min"] is not None:
        lines += [
            f"bbox min        {', '.join(_fmt(v) for v in bb['min'])}",
            f"bbox max        {', '.join(_fmt(v) for v in bb['max'])}",
            f"bbox size       {', '.join(_fmt(v) for v in bb['size'])}",
        ]
    lines += [
        f"opacity         min {_fmt(op['min'])}  median {_fmt(op['median'])}  max {_fmt(op['max'])}  "
        f"(< 1/255: {op['below_1_255']:,})",
        f"scale, largest  p5 {_fmt(smax['p5'])}  median {_fmt(smax['median'])}  p95 {_fmt(smax['p95'])}  "
        f"max {_fmt(smax['max'])}",
        f"scale, smallest p5 {_fmt(smin['p5'])}  median {_fmt(smin['median'])}  p95 {_fmt(smin['p95'])}",
        f"NaN/Inf rows    {stats['nonfinite_rows']:,}  (NaN rows {bad['nan_rows']:,}; NaN values "
        + (", ".join(f"{k} {v:,}" for k, v in bad["nan"].items() if v) or "none") + "; Inf values "
        + (", ".join(f"{k} {v:,}" for k, v in bad["inf"].items() if v) or "none") + ")",
        f"opacity +-inf   {bad['opacity_pos_inf']:,} / {bad['opacity_neg_inf']:,}  (fully opaque / transparent; "
        f"read as logit +-{OPACITY_LOGIT_LIMIT:.4g})",
        f"absurd scales   {bad['absurd_scale_rows']:,}  (largest scale wider than the scene's bounding box, or infinite)",
        f"zero quats      {stats['zero_norm_quats']:,}",
        f"normals         {'yes' if stats['has_normals'] else 'no'}",
        "extra columns   " + (", ".join(f"{k} ({v})" for k, v in stats["extra_columns"].items()) or "none"),
    ]
    click.echo("\n".join(lines))
