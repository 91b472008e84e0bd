"""``roodi-toolkit distill``: masks of the objects -> per-Gaussian object features of a trained scene (ROODI 3.1)."""

from __future__ import annotations

from typing import Any

import click

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.pipeline.segment import Click
from roodi_toolkit.plugins import load_plugin
from roodi_toolkit.run.distill import run_distill

from .common import overwrite_option, parse_key_values, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import Options, SettingsCommand

EXAMPLE = """Examples:

\b
  roodi-toolkit distill models/bedroom scenes/bedroom dist/bedroom              # the dataset's own masks
  roodi-toolkit distill models/bedroom scenes/bedroom dist/mine --masks my_masks/   # PNGs named like the views
  roodi-toolkit distill models/bedroom scenes/bedroom dist/ball --segmenter click --click r_003:41,57
  roodi-toolkit select dist/bedroom --object 2 ball.ply
  roodi-toolkit distill models/bedroom scenes/bedroom dist/sam --segmenter sam2 --click r_003:41,57 \\
      --option checkpoint=sam2.1_hiera_tiny.pt --option config=configs/sam2.1/sam2.1_hiera_t.yaml
"""


DISTILL_SETTINGS = Options("roodi_toolkit.pipeline.distill:DistillConfig")
"""distill's settings of DistillConfig (--iterations, --feature-lr, --classifier-lr, --seed)."""


@click.command(cls=SettingsCommand, epilog=EXAMPLE)
@click.argument("model_dir", type=click.Path(path_type=str))
@click.argument("data_dir", type=click.Path(path_type=str))
@click.argument("out_dir", type=click.Path(path_type=str))
@click.option("--segmenter", default="files", show_default=True,
              help="Segmenter plugin: files (mask PNGs or the dataset's masks), click, sam2, ...")
@click.option("--click", "clicks", multiple=True, metavar="VIEW:X,Y",
              help="A click on the target in one view, in the original photo's pixels (x right, y down, whatever "
                   "--downscale); repeatable.")
@click.option("--negative-click", "negative_clicks", multiple=True, metavar="VIEW:X,Y",
              help="A click on something that is not the target, in the same view (repeatable).")
@click.option("--masks", "mask_dir", type=click.Path(path_type=str), default=None,
              help="files segmenter: folder of mask PNGs named like the views (default: the dataset's masks).")
@click.option("--option", "options", multiple=True, metavar="KEY=VALUE",
              help="Segmenter option, e.g. checkpoint=PATH for sam2 (repeatable).")
@DISTILL_SETTINGS
@click.option("--downscale", type=click.FloatRange(1.0), default=None,
              help="Image downscale (default: the training run's, from MODEL_DIR/cfg.json).")
@click.option("--dataparser-transforms", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="With a nerfstudio export (splat.ply) as MODEL_DIR: its training run's dataparser_transforms.json, "
                   "which moves it back into the data's frame.")
@overwrite_option
@renderer_option
@quiet_option
def distill(model_dir: str, data_dir: str, out_dir: str, segmenter: str, clicks: tuple[str, ...],
            negative_clicks: tuple[str, ...], mask_dir: str | None,
            options: tuple[str, ...], downscale: float | None, dataparser_transforms: str | None, overwrite: bool,
            renderer: Any, quiet: bool, **settings: Any) -> None:
    """Distil object masks of DATA_DIR's views into per-Gaussian features of the scene model in MODEL_DIR (a
    roodi-toolkit train output; or an Inria or gsplat output folder, a gsplat ckpt_N_rank0.pt, a splat file, a
    nerfstudio export with --dataparser-transforms: checked against DATA_DIR's cameras and photos), written to the
    folder OUT_DIR.

    OUT_DIR gets features.npy (16 per Gaussian, in the model PLY's order), object_classifier.pt, object_masks/,
    distill.json (which model file, settings, loss, held-out IoU) and distill.png (rendered classes next to the masks).
    MODEL_DIR and DATA_DIR are only read. Then take objects out with roodi-toolkit select OUT_DIR.
    """
    opts = parse_key_values(options, "--option")
    parsed = []
    for texts, positive, hint in ((clicks, True, "--click"), (negative_clicks, False, "--negative-click")):
        for c in texts:
            try:
                parsed.append(Click.parse(c, positive))
            except ConfigError as exc:
                raise click.BadParameter(str(exc), param_hint=hint) from None
    load_plugin("segmenters", segmenter)  # an unknown or broken --segmenter fails before the images are read
    config = DISTILL_SETTINGS.config(settings)
    summary = run_distill(model_dir, data_dir, out_dir, segmenter=segmenter, clicks=parsed, mask_dir=mask_dir,
                          segmenter_options=opts, config=config, downscale=downscale, overwrite=overwrite,
                          progress=progress_factory(quiet), renderer=renderer,
                          dataparser_transforms=dataparser_transforms)
    ev = summary["held_out"]
    iou = f", held-out mean IoU {ev['mean_iou']:.3f} over {len(ev['views'])} views" if ev.get("views") else ""
    click.echo(f"distilled {summary['num_classes']} classes into {summary['num_gaussians']:,} Gaussians in "
               f"{summary['seconds']:.1f} s (final loss {summary['final_loss']:.4f}{iou})")
    click.echo(f"wrote {summary['out_dir']} (record {summary['record']}, picture {summary['picture']})")
