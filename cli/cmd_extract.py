"""``roodi-toolkit extract``: posed images in, clean object PLYs out (train, distil, select, prune, inpaint, fine-tune)."""

from __future__ import annotations

from typing import Any

import click

from .common import overwrite_option, progress_factory, quiet_option, renderer_option

EXAMPLE = """Example:

\b
  roodi-toolkit make-scene scenes/bedroom --preset bedroom --size 128x128
  roodi-toolkit extract scenes/bedroom out/ --object 2 --object 3 --iterations 2500
  roodi-toolkit extract scenes/bedroom out/ --object all                       # every object of the scene
  roodi-toolkit extract scenes/bedroom out_noinpaint/ --object 2 --model out/scene --distill out/distill \\
      --no-inpaint                                                     # ablation, reusing the first run's stages
"""


_OPTIONS = [
    click.option("--model", "model_dir", type=click.Path(path_type=str), default=None,
                 help="Use this trained scene (roodi-toolkit train output) instead of training one; only read."),
    click.option("--distill", "distill_dir", type=click.Path(path_type=str), default=None,
                 help="Use this distillation of --model (roodi-toolkit distill output) instead of distilling; "
                      "only read."),
    click.option("--downscale", type=click.FloatRange(1.0), default=None,
                 help="Image downscale [the --model's own, from its cfg.json; else 1]."),
    click.option("--iterations", type=click.IntRange(1), default=None, help="Scene training iterations [3000]."),
    click.option("--init", type=click.Choice(["auto", "points", "random", "depth"]), default="auto",
                 show_default=True, help="Scene initialisation (see roodi-toolkit train)."),
    click.option("--distill-iterations", type=click.IntRange(1), default=500, show_default=True),
    click.option("--threshold", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=0.3,
                 show_default=True, help="Selection probability."),
    click.option("--no-prune", is_flag=True, help="Skip pruning (ablation)."),
    click.option("--no-inpaint", is_flag=True, help="Skip occlusion reasoning, inpainting and fine-tuning (ablation)."),
    click.option("--distance", type=click.Choice(["w2", "euclidean"]), default="w2", show_default=True,
                 help="Pruning distance (euclidean: ablation)."),
    click.option("--rule", type=click.Choice(["robust", "paper", "clip"]), default="robust", show_default=True,
                 help="Pruning rule (paper: the paper's single pass)."),
    click.option("--single-stage", is_flag=True,
                 help="Learn the object features together with the scene instead of after it "
                      "(ablation: w/o two-stage)."),
    click.option("--inpainter", default="opencv", show_default=True,
                 help="Inpainter plugin (see roodi-toolkit plugins)."),
]


def extract_options(func: Any) -> Any:
    """Add the options of extract's stages (shared with ``batch extract``)."""
    for option in reversed(_OPTIONS):
        func = option(func)
    return func


def extract_config_from_options(*, downscale: float | None, iterations: int | None, init: str,
                                distill_iterations: int, threshold: float, no_prune: bool, no_inpaint: bool,
                                distance: str, rule: str, single_stage: bool, inpainter: str, **_: Any) -> Any:
    """Return the ExtractConfig the stage options describe."""
    from dataclasses import replace

    from roodi_toolkit.pipeline.distill import DistillConfig
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.pipeline.train import config_with
    from roodi_toolkit.prune.outliers import PruneConfig

    base = ExtractConfig()
    return replace(base, downscale=downscale, train=config_with(base.train, iterations=iterations, init=init),
                   distill=DistillConfig(iterations=distill_iterations), threshold=threshold, prune=not no_prune,
                   prune_config=PruneConfig(distance=distance, rule=rule), inpaint=not no_inpaint,
                   inpainter=inpainter, single_stage=single_stage)


@click.command(epilog=EXAMPLE)
@click.argument("data_dir", type=click.Path(path_type=str))
@click.argument("out_dir", type=click.Path(path_type=str))
@click.option("--object", "object_ids", multiple=True, required=True, metavar="ID|all",
              help="Instance id of an object to extract (repeat for several; they share one scene and distillation), "
                   "or 'all' for every object of the distillation.")
@extract_options
@overwrite_option
@renderer_option
@quiet_option
def extract(data_dir: str, out_dir: str, object_ids: tuple[str, ...], model_dir: str | None,
            distill_dir: str | None, overwrite: bool, renderer: Any, quiet: bool, **stage_options: Any) -> None:
    """Extract objects of DATA_DIR as clean 3DGS models into OUT_DIR/object_<ID>/object.ply.

    Re-running with the same OUT_DIR reuses the finished stages (scene, distillation, each object) that were made
    with the same settings, and says which it reused and which it made again; --overwrite makes every stage again.
    DATA_DIR, --model and --distill are only read.
    """
    from roodi_toolkit.pipeline.extract import extract_objects

    config = extract_config_from_options(**stage_options)
    if config.inpaint:  # an unknown or broken --inpainter fails now, not after the scene has been trained
        from roodi_toolkit.plugins import load_plugin

        load_plugin("inpainters", config.inpainter)
    report = extract_objects(data_dir, out_dir, object_ids, model_dir=model_dir, distill_dir=distill_dir,
                             config=config, overwrite=overwrite, progress=progress_factory(quiet), renderer=renderer)
    if report["reused"]:
        click.echo(f"reused finished stages: {', '.join(report['reused'])}")
    if report["recomputed"]:
        click.echo(f"made again: {', '.join(report['recomputed'])}")
    for oid, entry in report["objects"].items():
        note = f" (pruning skipped: {entry['prune_skipped']})" if "prune_skipped" in entry else ""
        click.echo(f"object {oid}: {entry['gaussians']:,} Gaussians -> {entry['object_ply']}{note}")
