"""``roodi-toolkit extract``: posed images in, clean object PLYs out (train, distil, select, prune, inpaint, fine-tune)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import click

from roodi_toolkit.pipeline.inpaint import get_inpainter
from roodi_toolkit.pipeline.segment import Click, SegmentPrompt
from roodi_toolkit.run.extract import extract_objects

from .common import overwrite_option, parse_floats, parse_key_values, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import Options, SettingsCommand

EXAMPLE = """Example:

\b
  roodi-toolkit make-scene scenes/bedroom --preset bedroom --size 128x128
  roodi-toolkit extract scenes/bedroom out/ --object 2 --object 3 --iterations 2500
  roodi-toolkit extract scenes/bedroom out/ --object all                       # every object of the scene
  roodi-toolkit extract scenes/bedroom out_noinpaint/ --object 2 --model out/scene --distill out/distill \\
      --no-inpaint                                                     # ablation, reusing the first run's stages
  roodi-toolkit train captures/statue models/statue --downscale 4
  roodi-toolkit extract statue_out/ --model models/statue --click 520,300 --view DSC_5283
      # data folder and resolution from the model's cfg.json; the click in the photo's own pixels
  roodi-toolkit extract out/ --model inria_output/ --click 520,300          # an Inria model: data from cfg_args
  roodi-toolkit extract capture/ out/ --model exports/splat.ply \
      --dataparser-transforms outputs/capture/splatfacto/RUN/dataparser_transforms.json --click 520,300
"""


EXTRACT_SETTINGS = Options("roodi_toolkit.pipeline.extract:ExtractConfig", only=(
    "downscale", "train.iterations", "train.init", "distill.iterations", "distill.max_views", "threshold", "prune",
    "inpaint", "prune_config.distance", "prune_config.rule", "single_stage", "inpainter"))
"""The settings of ExtractConfig that extract and batch extract offer (--distance and --rule: StatisticalSettings')."""

_OPTIONS = [
    click.option("--model", "model_dir", type=click.Path(path_type=str), default=None,
                 help="Use this trained scene instead of training one; only read: a roodi-toolkit train output, an "
                      "Inria or gsplat output folder, a gsplat ckpt_N_rank0.pt, or any splat file (with DATA_DIR; a "
                      "nerfstudio export with --dataparser-transforms)."),
    click.option("--distill", "distill_dir", type=click.Path(path_type=str), default=None,
                 help="Use this distillation of --model (roodi-toolkit distill output) instead of distilling; "
                      "only read."),
    EXTRACT_SETTINGS,
    click.option("--inpainter-option", "inpainter_options", multiple=True, metavar="KEY=VALUE",
                 help="Inpainter option (repeatable), e.g. model=PATH steps=30 for sdxl, method=ns for opencv; the "
                      "keyword arguments of the plugin's class (docs/plugins.md)."),
]


def extract_options(func: Any) -> Any:
    """Add the options of extract's stages (shared with ``batch extract``)."""
    for option in reversed(_OPTIONS):
        func = option(func)
    return func


def extract_config_from_options(*, inpainter_options: tuple[str, ...] = (), **values: Any) -> Any:
    """Return the ExtractConfig the stage options describe."""
    return replace(EXTRACT_SETTINGS.config(values),
                   inpainter_options=parse_key_values(inpainter_options, "--inpainter-option"))


@click.command(cls=SettingsCommand, epilog=EXAMPLE)
@click.argument("paths", nargs=-1, required=True, metavar="[DATA_DIR] OUT_DIR", type=click.Path(path_type=str))
@click.option("--object", "object_ids", multiple=True, metavar="ID|all",
              help="Instance id of an object to extract (repeat for several; they share one scene and distillation), "
                   "or 'all' for every object of the distillation; for datasets with instance masks "
                   "[with --click: 1, the clicked object].")
@click.option("--click", "clicks", multiple=True, metavar="X,Y",
              help="A click on the object in --view, in the original photo's pixels (x right, y down, whatever "
                   "--downscale); repeatable. The click segmenter grows it through the scene's Gaussians into "
                   "every training view.")
@click.option("--negative-click", "negative_clicks", multiple=True, metavar="X,Y",
              help="A click in --view on something that is not the object (the table it stands on, a neighbour); "
                   "repeatable.")
@click.option("--view", default=None, metavar="IMAGE_NAME",
              help="The image the clicks are in (file name without extension) [the first training image].")
@click.option("--segmenter", default=None,
              help="Segmenter plugin whose masks are distilled: files (the dataset's instance masks, or --masks), "
                   "click, sam2, ... [click with --click, else files].")
@click.option("--segmenter-option", "segmenter_options", multiple=True, metavar="KEY=VALUE",
              help="Segmenter option (repeatable), e.g. region_radius=0.5 for click (ClickSettings) or "
                   "checkpoint=PATH for sam2.")
@click.option("--masks", "mask_dir", type=click.Path(file_okay=False, path_type=str), default=None,
              help="files segmenter: a folder of mask PNGs named like the views [the dataset's own masks].")
@extract_options
@click.option("--dataparser-transforms", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="With a nerfstudio export (ns-export gaussian-splat's splat.ply) as --model: its training run's "
                   "dataparser_transforms.json, which moves it back into the data's frame.")
@overwrite_option
@renderer_option
@quiet_option
def extract(paths: tuple[str, ...], object_ids: tuple[str, ...], clicks: tuple[str, ...],
            negative_clicks: tuple[str, ...], view: str | None,
            segmenter: str | None, segmenter_options: tuple[str, ...], mask_dir: str | None,
            model_dir: str | None, distill_dir: str | None, dataparser_transforms: str | None,
            overwrite: bool, renderer: Any, quiet: bool, **stage_options: Any) -> None:
    """Extract objects of DATA_DIR as clean 3DGS models into OUT_DIR/object_<ID>/object.ply.

    The object is chosen by instance id (--object, datasets with masks), by clicks (--click X,Y --view IMAGE_NAME)
    or by a segmenter plugin's masks (--segmenter). With --model, DATA_DIR and --downscale default to the ones its
    record names (cfg.json; an Inria model's cfg_args, a gsplat run's cfg.yml); a model from another tool is checked
    against the data's cameras and photos, and refused, with the reason, when they do not fit.

    Re-running with the same OUT_DIR reuses the finished stages (scene, distillation, each object) that were made
    with the same settings and says which it reused; a stage made with other settings (another --inpainter, say) is
    not replaced without --overwrite, which makes every stage again (or write to another OUT_DIR, with --model
    OUT_DIR/scene --distill OUT_DIR/distill to reuse the scene). DATA_DIR, --model and --distill are only read.
    """
    if len(paths) > 2:
        raise click.UsageError(f"expected [DATA_DIR] OUT_DIR, got {len(paths)} paths")
    if len(paths) == 1 and model_dir is None:
        raise click.UsageError("give DATA_DIR OUT_DIR, or OUT_DIR with --model (whose cfg.json names the data)")
    data_dir, out_dir = (None, paths[0]) if len(paths) == 1 else paths
    if (view is not None or negative_clicks) and not clicks:
        raise click.UsageError("--view and --negative-click go with a click on the object; give --click X,Y too")
    parsed = tuple(Click(view or "", *parse_floats(c, 2, "--click")) for c in clicks) + tuple(
        Click(view or "", *parse_floats(c, 2, "--negative-click"), positive=False) for c in negative_clicks)
    segmenter = segmenter or ("click" if clicks else "files")
    if clicks and segmenter == "files":
        raise click.UsageError("the files segmenter reads masks and takes no --click; leave --segmenter out (click) "
                               "or name a click segmenter such as sam2")
    if not object_ids:
        if segmenter == "files":
            raise click.UsageError("say which object: --object ID (a dataset with instance masks) or --click X,Y "
                                   "[--view IMAGE_NAME] (any dataset)")
        object_ids = ("1",)  # a click or prompt segmenter's binary masks: 1 is the target
    config = extract_config_from_options(**stage_options)
    opts = parse_key_values(segmenter_options, "--segmenter-option")
    config = replace(config, segmenter=segmenter, segmenter_options=opts,
                     prompt=SegmentPrompt(clicks=parsed, mask_dir=Path(mask_dir) if mask_dir else None))
    if config.inpaint:  # an unknown or broken --inpainter, or options it does not take, fail now, not after training
        get_inpainter(config.inpainter, **config.inpainter_options)
    report = extract_objects(data_dir, out_dir, object_ids, model_dir=model_dir, distill_dir=distill_dir,
                             config=config, overwrite=overwrite, progress=progress_factory(quiet), renderer=renderer,
                             replace_changed=False, dataparser_transforms=dataparser_transforms)
    for note in report.get("model_notes", []):
        click.echo(f"model: {note}")
    if report["reused"]:
        click.echo(f"reused finished stages: {', '.join(report['reused'])}")
    if report["recomputed"]:
        click.echo(f"made again: {', '.join(report['recomputed'])}")
    for oid, entry in report["objects"].items():
        note = f" (pruning skipped: {entry['prune_skipped']})" if "prune_skipped" in entry else ""
        click.echo(f"object {oid}: {entry['gaussians']:,} Gaussians -> {entry['object_ply']}{note}")
