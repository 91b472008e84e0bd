"""``roodi-toolkit render``: images, depth or alpha of a 3DGS PLY from an orbit or a dataset's cameras."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.io.dataset import load_cameras
from roodi_toolkit.io.files import prepare_output_dir
from roodi_toolkit.io.splat import input_paths, read_cloud
from roodi_toolkit.render.settings import OrbitSettings
from roodi_toolkit.render.views import framing_orbit, render_views, resolve_up

from .common import check_render_size, overwrite_option, parse_floats, parse_size, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import config_from_options, config_options

EPILOG = """Examples:

\b
  roodi-toolkit render scene.ply renders/ --orbit 8 --elevation 30
  roodi-toolkit render scene.ply depth/ --orbit 4 --what depth --size 640x480
  roodi-toolkit render scene.ply views/ --cameras dataset/transforms_test.json
  roodi-toolkit render scene.ply views/ --cameras colmap_scene/ --renderer gsplat
  roodi-toolkit render before.ply b/ --up colmap_scene/            # orbit upright: the capture's camera up
  roodi-toolkit render after.ply a/ --frame-like before.ply        # the very same views as before.ply's
"""


@click.command(epilog=EPILOG)
@click.argument("ply", metavar="IN", type=click.Path(path_type=str))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=str))
@click.option("--cameras", "cameras_path", type=click.Path(path_type=str),
              help="Render a dataset's cameras: a Blender transforms_*.json, a Blender folder or a COLMAP folder.")
@config_options(OrbitSettings)
@click.option("--up", default=None,
              help="Orbit up axis: X,Y,Z; a dataset or camera file (its cameras' mean up); or auto (the default): "
              "the training cameras of the model IN belongs to (this toolkit's or the Inria code's), else the "
              "format's convention (PlayCanvas and SPZ files are y-down, nerfstudio's z-up), else a ground plane "
              "found in the cloud, else z up. Which one is used is printed.")
@click.option("--frame-like", "frame_like", type=click.Path(path_type=str), default=None,
              help="Frame the orbit on this other cloud (centre, radius, up) so that several clouds, e.g. before "
              "and after pruning, are rendered from the same views.")
@click.option("--size", "size_text", default=None,
              help="Image size WxH (orbit default 512x512; dataset cameras are rescaled to it).")
@click.option("--what", type=click.Choice(["rgb", "depth", "alpha"]), default="rgb", show_default=True,
              help="rgb: colour PNG; depth: 16-bit PNG + coloured preview (scale in render.json); alpha: 8-bit PNG.")
@click.option("--background", default="0,0,0", show_default=True, help="Background colour r,g,b in [0, 1].")
@renderer_option
@click.option("--filter-nan", is_flag=True,
              help="Drop Gaussians with NaN/Inf values instead of refusing the file (+-inf opacities are read as "
                   "fully opaque / transparent and kept).")
@overwrite_option
@quiet_option
def render(ply: str, out_dir: str, cameras_path: str | None, up: str | None, frame_like: str | None,
           size_text: str | None, what: str, background: str, renderer: Any, filter_nan: bool, overwrite: bool,
           quiet: bool, **settings: Any) -> None:
    """Render IN (any splat format) into OUT_DIR from an orbit around the cloud or from a dataset's cameras."""
    orbit = config_from_options(OrbitSettings, settings)
    bg = parse_floats(background, 3, "--background")
    if not all(0.0 <= v <= 1.0 for v in bg):
        raise click.BadParameter(f"colour components must be in [0, 1], got {background!r}", param_hint="--background")
    size = parse_size(size_text) if size_text else None
    if cameras_path and orbit.orbit is not None:
        raise click.UsageError("give either --cameras or --orbit, not both")
    if cameras_path and (frame_like or up):
        raise click.UsageError("--frame-like and --up frame an orbit; --cameras renders the dataset's own views")

    cloud = read_cloud(ply)
    if filter_nan:
        cloud = cloud.select(~cloud.nonfinite_rows())
    cloud.require_finite(ply)
    extra = {}
    if cameras_path:
        cams = load_cameras(cameras_path)
        if not cams:
            raise ConfigError(f"{cameras_path}: holds no cameras (no frames); give a dataset with views")
        if size is not None:
            cams = [c.with_size(*size) for c in cams]
    else:
        frame_path = frame_like or ply
        frame_cloud = cloud
        if frame_like:
            frame_cloud = read_cloud(frame_like)
            frame_cloud = frame_cloud.select(~frame_cloud.nonfinite_rows())
        up_axis, up_from = resolve_up(up, frame_path, frame_cloud.means)
        w, h = size or (512, 512)
        cams = framing_orbit(frame_cloud, orbit.views, elevation_deg=orbit.elevation, radius=orbit.radius, width=w,
                             height=h, fov_x_deg=orbit.fov, up=up_axis)
        extra = {"orbit": {"framed_on": str(frame_path), "up": up_axis.tolist(), "up_from": up_from}}
        if not quiet:
            click.echo(f"orbit up {', '.join(f'{v:.3g}' for v in up_axis + 0.0)}: {up_from}", err=True)
    big = max(cams, key=lambda c: c.width * c.height)
    check_render_size(big.width, big.height, f"--size {size_text}" if size_text else cameras_path or "--size")
    # a transforms_*.json stands for its whole dataset folder: rendering into its images/ would overwrite them
    camera_folder = str(Path(cameras_path).parent) if cameras_path and Path(cameras_path).is_file() else None
    out = prepare_output_dir(out_dir, overwrite=overwrite, inputs=[*input_paths(ply), cameras_path, camera_folder,
                                                                 *(input_paths(frame_like) if frame_like else [])])
    record = render_views(cloud, cams, out, what=what, renderer=renderer, background=bg,
                          progress=progress_factory(quiet), extra=extra)
    if not quiet:
        click.echo(f"wrote {len(record['views'])} {what} view(s) to {out}", err=True)
