"""``roodi-toolkit info``: what is in a 3DGS PLY file."""

from __future__ import annotations

import json

import click


def _fmt(x: float) -> str:
    return f"{x:.4g}"


@click.command(epilog="Example:\n\n\b\n  roodi-toolkit info scene.ply\n  roodi-toolkit info scene.ply --json > info.json")
@click.argument("ply", type=click.Path(dir_okay=True, path_type=str))
@click.option("--json", "as_json", is_flag=True, help="Print machine-readable JSON instead of a table.")
def info(ply: str, as_json: bool) -> None:
    """Show count, SH degree, bounding box, opacity and scale statistics, bad rows and the file variant of PLY."""
    from roodi_toolkit import describe_cloud, ply_info, read_ply

    layout = ply_info(ply)
    cloud = read_ply(ply)
    stats = describe_cloud(cloud)
    stats["file"] = {"path": layout.path, "format": layout.format, "variant": layout.variant,
                     "bytes": layout.file_size, "properties": len(layout.property_names)}
    if as_json:
        click.echo(json.dumps(stats, indent=2))
        return
    bb = stats["bbox"]
    op = stats["opacity"]
    smax, smin = stats["scale_max_axis"], stats["scale_min_axis"]
    lines = [
        f"file            {layout.path}",
        f"variant         {layout.variant} ({layout.format}, {len(layout.property_names)} properties, "
        f"{layout.file_size:,} bytes)",
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
        f"NaN/Inf rows    {stats['nonfinite_rows']:,}",
        f"zero quats      {stats['zero_norm_quats']:,}",
        f"normals         {'yes' if stats['has_normals'] else 'no'}",
        "extra columns   " + (", ".join(f"{k} ({v})" for k, v in stats["extra_columns"].items()) or "none"),
    ]
    click.echo("\n".join(lines))
