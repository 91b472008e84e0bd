"""``roodi-toolkit convert``: turn a splat file of any readable format into PLY, compressed PLY or SPZ."""

from __future__ import annotations

import click

from .common import overwrite_option

EPILOG = """Examples:

\b
  roodi-toolkit convert scene.spz scene.ply
  roodi-toolkit convert scene.ply scene.compressed.ply
  roodi-toolkit convert scene/meta.json scene.spz --overwrite
"""


@click.command(epilog=EPILOG)
@click.argument("input_path", metavar="IN", type=click.Path(path_type=str))
@click.argument("output_path", metavar="OUT", type=click.Path(dir_okay=False, path_type=str))
@click.option("--filter-nan", is_flag=True, help="Drop Gaussians with NaN/Inf values (the quantised formats refuse "
                                                  "them otherwise); +-inf opacities are kept as fully opaque/transparent.")
@click.option("--filter-absurd-scales", is_flag=True,
              help="Drop Gaussians whose largest scale is wider than the scene's bounding box (what info counts).")
@overwrite_option
def convert(input_path: str, output_path: str, filter_nan: bool, filter_absurd_scales: bool, overwrite: bool) -> None:
    """Convert IN (PLY, compressed PLY, SPZ, SOG .sog/meta.json, .splat, .ksplat; detected by content) to OUT.

    OUT's extension picks the format: .ply, .compressed.ply or .spz. OUT is written atomically, never over IN.
    """
    from roodi_toolkit.io.files import check_output
    from roodi_toolkit.io.splat import input_paths, output_format, read_cloud_report, write_cloud

    fmt = output_format(output_path)  # refuse an unknown extension before reading
    check_output(output_path, overwrite=overwrite, inputs=input_paths(input_path))
    cloud, report = read_cloud_report(input_path)
    dropped = 0
    if filter_nan:
        bad = cloud.nonfinite_rows()
        dropped = int(bad.sum())
        cloud = cloud.select(~bad)
    extra = f"; dropped {dropped:,} NaN/Inf rows" if dropped else ""
    if filter_absurd_scales:
        from roodi_toolkit.stats import absurd_scale_rows

        wide = absurd_scale_rows(cloud)
        cloud = cloud.select(~wide)
        extra += f"; dropped {int(wide.sum()):,} Gaussians wider than the scene" if wide.any() else ""
    write_cloud(cloud, output_path)
    inf = report.opacity_pos_inf + report.opacity_neg_inf
    extra += f"; {inf:,} +-inf opacities read as fully opaque/transparent" if inf else ""
    click.echo(f"converted {len(cloud):,} Gaussians from {report.format} to {fmt}: wrote {output_path}{extra}")
