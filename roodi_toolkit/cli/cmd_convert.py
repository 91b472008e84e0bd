"""``roodi-toolkit convert``: turn a splat file of any readable format into PLY, compressed PLY or SPZ, optionally
moved, turned and scaled (splat-transform's ``-t``, ``-r``, ``-s``, in the order given)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click
import numpy as np

from roodi_toolkit.io.files import check_output
from roodi_toolkit.io.other_models import GSPLAT_CKPT
from roodi_toolkit.io.splat import input_paths, output_format, read_cloud_report, write_cloud
from roodi_toolkit.render.upright import resolve_up
from roodi_toolkit.similarity import Similarity, rotation_between, splat_transform_actions, transform_cloud
from roodi_toolkit.stats import absurd_scale_rows

from .common import overwrite_option, parse_floats

EPILOG = """Examples:

\b
  roodi-toolkit convert scene.spz scene.ply
  roodi-toolkit convert scene.ply scene.compressed.ply
  roodi-toolkit convert scene/meta.json scene.spz --overwrite
  roodi-toolkit convert scene.ply turned.ply -r 0,0,90 -t 0,1,0 -s 2     # as splat-transform scene.ply -r ... out
  roodi-toolkit convert biker.spz upright.ply --up 0,-1,0                 # its up (-y) becomes +z
  roodi-toolkit convert splat.ply scene.ply --up ../captures/room         # the capture's camera up becomes +z
  roodi-toolkit convert exports/splat.ply scene.ply --data captures/room \
      --dataparser-transforms outputs/room/splatfacto/RUN/dataparser_transforms.json   # back in the capture's frame
  roodi-toolkit convert results/garden/ckpts/ckpt_29999_rank0.pt garden.ply  # gsplat's world undone (data: cfg.yml)
"""

TRANSFORM_OPTIONS = {"translate": "--translate", "rotate": "--rotate", "scale": "--scale"}


class _OrderedActions(click.Command):
    """Remembers the order in which the transform options were given (click groups repeated values by option):
    splat-transform applies ``-t``, ``-r`` and ``-s`` in command-line order, and so does ``convert``."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        parser = self.make_parser(ctx)
        opts, _, order = parser.parse_args(args=list(args))
        values = {name: list(opts.get(name) or []) for name in TRANSFORM_OPTIONS}
        ctx.meta["convert_actions"] = [(p.name, values[p.name].pop(0)) for p in order
                                       if getattr(p, "name", None) in TRANSFORM_OPTIONS and values[p.name]]
        return super().parse_args(ctx, args)


@click.command(cls=_OrderedActions, epilog=EPILOG)
@click.argument("input_path", metavar="IN", type=click.Path(path_type=str))
@click.argument("output_path", metavar="OUT", type=click.Path(dir_okay=False, path_type=str))
@click.option("--filter-nan", is_flag=True, help="Drop Gaussians with NaN/Inf values (the quantised formats refuse "
                                                  "them otherwise); +-inf opacities are kept as fully opaque/transparent.")
@click.option("--filter-absurd-scales", is_flag=True,
              help="Drop Gaussians whose largest scale is wider than the scene's bounding box (what info counts).")
@click.option("-t", "--translate", multiple=True, metavar="X,Y,Z",
              help="Move the Gaussians by X,Y,Z (repeatable; splat-transform's -t: in its PlayCanvas axes, which are "
                   "the file's with x and y negated).")
@click.option("-r", "--rotate", multiple=True, metavar="X,Y,Z",
              help="Turn the Gaussians by Euler angles in degrees, about x, then y, then z (repeatable; "
                   "splat-transform's -r, in its axes). Every SH band turns with them.")
@click.option("-s", "--scale", multiple=True, metavar="S",
              help="Scale the Gaussians (positions and sizes) by S > 0 about the origin (repeatable; "
                   "splat-transform's -s).")
@click.option("--data", "data_dir", type=click.Path(path_type=str), default=None,
              help="IN is a trained model in another frame than its data (a gsplat checkpoint or result folder, a "
                   "nerfstudio export with --dataparser-transforms, an Inria folder): move it into this data "
                   "folder's frame [the data its record names].")
@click.option("--dataparser-transforms", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="IN is a nerfstudio export: its training run's dataparser_transforms.json (needs --data).")
@click.option("--up", "up_spec", default=None, metavar="X,Y,Z|DATASET",
              help="Turn the splat so that this direction, in the file's own axes, becomes +z (the toolkit's up), "
                   "before the other moves: X,Y,Z, or a dataset or camera file whose cameras' mean up is taken.")
@overwrite_option
def convert(input_path: str, output_path: str, filter_nan: bool, filter_absurd_scales: bool,
            translate: tuple[str, ...], rotate: tuple[str, ...], scale: tuple[str, ...], data_dir: str | None,
            dataparser_transforms: str | None, up_spec: str | None, overwrite: bool) -> None:
    """Convert IN (PLY, compressed PLY, SPZ, SOG .sog/meta.json, .splat, .ksplat; detected by content) to OUT.

    OUT's extension picks the format: .ply, .compressed.ply or .spz. OUT is written atomically, never over IN.
    -t, -r and -s move the splat exactly as splat-transform 2.7.1 does with the same numbers, in the order given
    (positions, rotations, sizes and every SH band; checked against its output).

    IN may also be a model another tool trained (a gsplat checkpoint or result folder, an Inria output folder, a
    nerfstudio export with --dataparser-transforms and --data): OUT is then its scene in the data's frame, where the
    other commands expect it.
    """
    fmt = output_format(output_path)  # refuse an unknown extension before reading
    move = _moves(click.get_current_context().meta.get("convert_actions", []), up_spec)
    check_output(output_path, overwrite=overwrite, inputs=[*input_paths(input_path), data_dir, dataparser_transforms,
                                                           *([up_spec] if up_spec and _is_path(up_spec) else [])])
    model_note = ""
    if data_dir is not None or dataparser_transforms is not None or _is_model(input_path):
        from roodi_toolkit.io.model import open_model  # lazy: the model readers import torch; splat files need none

        model = open_model(input_path, data_dir, dataparser_transforms=dataparser_transforms)
        if model.frames:
            raise click.UsageError(f"{input_path}: two gsplat versions normalise this data differently and only the "
                                   "photos can tell which one trained it; give it to extract or distill (which "
                                   "check the photos) instead of convert")
        cloud = model.read_cloud()
        report = _ModelReport(model.kind)
        model_note = f"; {model.kind} model moved into {model.config.get('data_dir')}'s frame" \
            if model.to_data is not None else ""
    else:
        cloud, report = read_cloud_report(input_path)
    dropped = 0
    if filter_nan:
        bad = cloud.nonfinite_rows()
        dropped = int(bad.sum())
        cloud = cloud.select(~bad)
    extra = (f"; dropped {dropped:,} NaN/Inf rows" if dropped else "") + model_note
    if filter_absurd_scales:
        wide = absurd_scale_rows(cloud)
        cloud = cloud.select(~wide)
        extra += f"; dropped {int(wide.sum()):,} Gaussians wider than the scene" if wide.any() else ""
    if move is not None:
        cloud = transform_cloud(cloud, move)
        extra += f"; moved ({_describe(move)})"
    write_cloud(cloud, output_path)
    inf = report.opacity_pos_inf + report.opacity_neg_inf
    extra += f"; {inf:,} +-inf opacities read as fully opaque/transparent" if inf else ""
    click.echo(f"converted {len(cloud):,} Gaussians from {report.format} to {fmt}: wrote {output_path}{extra}")


class _ModelReport:
    """What :func:`~roodi_toolkit.io.splat.read_cloud_report` says of a file, for a model read through its folder."""

    def __init__(self, kind: str) -> None:
        self.format = f"a {kind} model"
        self.opacity_pos_inf = self.opacity_neg_inf = 0


def _is_model(path: str) -> bool:
    """Whether IN is a model folder or a gsplat checkpoint rather than a splat file."""
    p = Path(path)
    return (p.is_dir() and not (p / "meta.json").is_file()) or GSPLAT_CKPT.fullmatch(p.name) is not None


def _is_path(spec: str) -> bool:
    return Path(spec).exists()


def _moves(actions: list[tuple[str, str]], up_spec: str | None) -> Any:
    """Return the similarity the --up and -t/-r/-s options describe, or None when there are none."""
    parsed: list[tuple[str, Any]] = []
    for kind, text in actions:
        name = TRANSFORM_OPTIONS[kind]
        if kind == "scale":
            (value,) = parse_floats(text, 1, name)
            if value <= 0:
                raise click.BadParameter(f"the scale must be > 0, got {text!r}", param_hint=name)
            parsed.append((kind, value))
        else:
            parsed.append((kind, parse_floats(text, 3, name)))
    total = None
    if up_spec is not None:
        if up_spec.strip().lower() == "auto":
            raise click.BadParameter("give the direction (X,Y,Z) or a dataset whose cameras tell it", param_hint="--up")
        up = resolve_up(up_spec, "").vector
        total = Similarity(rotation=rotation_between(up, (0.0, 0.0, 1.0)))
    if parsed:
        moves = splat_transform_actions(parsed)
        total = moves if total is None else total.then(moves)
    return total


def _describe(move: Any) -> str:
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(move.rotation)) - 1.0) / 2.0))))
    t = ", ".join(f"{v:.4g}" for v in move.translation)
    return f"turned {angle:.3g} degrees, scaled by {move.scale:.4g}, then moved by {t}"
