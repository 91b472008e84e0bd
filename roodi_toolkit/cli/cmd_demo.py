"""``roodi-toolkit demo``: the README's main job on generated data (no GPU, no downloads): extract one object."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import click

from roodi_toolkit.pipeline.train import config_with
from roodi_toolkit.plugins import load_plugin
from roodi_toolkit.synth.demo import ExtractDemoConfig, run_extract_demo, run_prune_demo

from .common import overwrite_option, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import Options, SettingsCommand

SURFACES = ("ant", "sphere", "torus", "box")

EXAMPLE = """Example:

\b
  roodi-toolkit demo demo-out                       # about 5 minutes on 2 cores
  roodi-toolkit demo demo-out --overwrite --preset livingroom --seed 5
  roodi-toolkit demo small --size 64 --train-views 24 --iterations 800 --max-gaussians 8000
  roodi-toolkit demo seed1 --train-seed 1           # the same scene trained again: how much the figures move
                                                    # from run to run (docs/benchmark.md, "Run to run")
  roodi-toolkit demo prune-out --prune-only         # the planted-floater pruning demo (seconds)
"""

# parameter -> flag of the demo's own options that only the extraction demo takes (None when not given: the
# library's default); the options of EXTRACT_OPTIONS are the extraction demo's too
EXTRACT_ONLY = {"max_gaussians": "--max-gaussians"}


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


def _scores(ev) -> str:
    lpips = f"{ev.lpips:.3f}" if ev.lpips is not None else "unavailable (no local weights)"
    return f"PSNR {ev.psnr:.2f} dB, SSIM {ev.ssim:.3f}, LPIPS {lpips}, IoU {ev.iou:.3f}"


DEMO_CONFIG = "roodi_toolkit.synth.demo:ExtractDemoConfig"

PRESET_SETTING = Options(DEMO_CONFIG, unset=True, only=("preset",))
"""The demo's scene preset (--preset); unset: the demo's own (kitchen)."""

OBJECT_SETTING = Options(DEMO_CONFIG, unset=True, only=("object_id",))
"""The demo's target (--object); unset: the target other objects hide most."""

SCENE_SETTINGS = Options(DEMO_CONFIG, within="scene", unset=True, only=("width", "train_views", "test_views"))
"""The demo's scene's image size and views (--size, --train-views, --test-views), as make-scene's; unset: the
demo's own (128x128, 50, 12)."""

DEMO_SETTINGS = Options(DEMO_CONFIG, within="extract", unset=True,
                        only=("train.iterations", "distill.iterations", "inpainter"))
"""The demo's settings of its ExtractConfig (--iterations, --distill-iterations, --inpainter); unset: the demo's own
(not given, --prune-only may go with them)."""

DEMO_REFINE_SETTINGS = Options(DEMO_CONFIG, within="extract", unset=True,
                               only=("finetune.iterations", "occlusion.size"))
"""The demo's settings of its refinement (--finetune-iterations, --view-size), unset as DEMO_SETTINGS' (a second set
only to keep them where ``--help`` lists them)."""

TRAIN_SEED_SETTING = Options(DEMO_CONFIG, within="extract", unset=True, only=("train.seed",),
                             flags={"train.seed": "--train-seed"})
"""The seed of the scene training, TrainConfig.seed, as --train-seed (the demo's --seed is the scene's)."""

OCCLUDED_SETTING = Options(DEMO_CONFIG, within="scene", unset=True, only=("occluded",),
                           flags={"occluded": "--occluded/--no-occluded"})
"""The scene's occluded variant: the demo's default, so the demo offers --no-occluded too."""

EXTRACT_OPTIONS = (PRESET_SETTING, OBJECT_SETTING, SCENE_SETTINGS, DEMO_SETTINGS, TRAIN_SEED_SETTING,
                   DEMO_REFINE_SETTINGS, OCCLUDED_SETTING)
"""The options of the demo's settings, all the extraction demo's (--prune-only refuses them)."""


def _extract_only(params: dict[str, Any]) -> list[str]:
    """Return the flags given that only the extraction demo takes, in ``--help``'s order."""
    flags = dict(EXTRACT_ONLY)
    flags.update((o.param, o.option) for options in EXTRACT_OPTIONS for o in options.offered())
    order = [p.name for p in click.get_current_context().command.params]
    return [flags[name] for name in sorted(flags, key=order.index) if params[name] is not None]


@click.command(cls=SettingsCommand, epilog=EXAMPLE)
@click.argument("out_dir", type=click.Path(path_type=str), default="demo-out")
@PRESET_SETTING
@click.option("--seed", type=int, default=None,
              help="Seed of the generated scene [2] (with --prune-only: of the generated cloud [0]).")
@OBJECT_SETTING
@SCENE_SETTINGS
@DEMO_SETTINGS
@TRAIN_SEED_SETTING
@click.option("--max-gaussians", type=click.IntRange(2), default=None,
              help="Most Gaussians the scene may grow to; it starts from half as many [30000].")
@DEMO_REFINE_SETTINGS
@OCCLUDED_SETTING
@click.option("--prune-only", is_flag=True, help="Run the planted-floater pruning demo instead (seconds).")
@click.option("--surface", type=click.Choice(SURFACES), default=None,
              help="With --prune-only: the generated object's surface [ant].")
@overwrite_option
@renderer_option
@quiet_option
def demo(out_dir: str, seed: int | None, max_gaussians: int | None, prune_only: bool, surface: str | None,
         overwrite: bool, renderer: Any, quiet: bool, **settings: Any) -> None:
    """Extract one object from a generated scene into OUT_DIR, score it, and say where the PLY and pictures are.

    Generates a cluttered scene (make-scene), trains it, distils its instance masks, then selects, prunes, completes
    the hidden parts (the weight-free symmetry fill: a mirror image where one agrees, and new Gaussians from the
    lowest seen part down to the floor) and fine-tunes the target; scores it (PSNR, SSIM, LPIPS, IoU, and inside the
    part no training view saw) against the target's object-alone views; writes
    OUT_DIR/extraction/object_<ID>/object.ply, OUT_DIR/summary.png and OUT_DIR/report.json. The defaults take about
    5 minutes on 2 CPU cores.
    """
    params = click.get_current_context().params
    given = _extract_only(params)
    progress = progress_factory(quiet)
    if prune_only:
        if given:
            raise click.UsageError(f"{', '.join(given)}: options of the extraction demo, not of --prune-only")
        _prune_demo(out_dir, seed, surface, overwrite, progress)
        return
    if surface is not None:
        raise click.UsageError("--surface is an option of --prune-only")
    base = ExtractDemoConfig()
    scene = OCCLUDED_SETTING.config(params, base=SCENE_SETTINGS.config(params, base=base.scene))
    ex = base.extract
    for options in (DEMO_SETTINGS, TRAIN_SEED_SETTING, DEMO_REFINE_SETTINGS):
        ex = options.config(params, base=ex)
    train = config_with(ex.train, cap_max=max_gaussians,
                        init_num_points=None if max_gaussians is None else max(1, max_gaussians // 2))
    extract = replace(ex, train=train)
    if extract.inpaint:  # an unknown or broken --inpainter fails now, not after the scene has been trained
        load_plugin("inpainters", extract.inpainter)
    target = OBJECT_SETTING.config(params, base=PRESET_SETTING.config(params, base=base))  # --preset, --object
    config = replace(target, seed=base.seed if seed is None else seed, scene=scene, extract=extract)
    res = run_extract_demo(out_dir, config, overwrite=overwrite, progress=progress, renderer=renderer)

    st, g = res.stages, res.gaussians
    psnr = f", held-out PSNR {res.scene_psnr:.2f} dB" if res.scene_psnr is not None else ""
    click.echo(f"extracted {res.object_name} (object {res.object_id}) from a generated {config.preset} scene "
               f"(seed {config.seed}, {scene.width}x{scene.height}, {scene.train_views} views) in "
               f"{_duration(res.seconds)}; "
               f"{res.hidden_fraction:.0%} of it is hidden by other objects in the training views")
    click.echo(f"  stages: scene {_duration(st['make_scene'])}, train {_duration(st['train'])}, "
               f"distill {_duration(st['distill'])}, select+prune {_duration(st['select_prune'])}, "
               f"inpaint+fine-tune {_duration(st['refine'])}, evaluate {_duration(st['evaluate'])} "
               f"(load average {res.load_average[1]:.1f})")
    click.echo(f"  scene model {g['scene']:,} Gaussians{psnr}; object {g['selected']:,} Gaussians selected and "
               f"pruned, {g['object']:,} after fine-tuning")
    click.echo(f"  {len(res.evaluation.views)} object-alone test views: {_scores(res.evaluation)}")
    click.echo(f"  before inpainting and fine-tuning: {_scores(res.before)}")
    ev, bf = res.evaluation, res.before
    if ev.ns_iou is not None and bf.ns_iou is not None:
        pixels = sum(v.ns_pixels for v in ev.views)
        click.echo(f"  never seen in training ({pixels:,} pixels over {sum(v.ns_pixels > 0 for v in ev.views)} "
                   f"views): PSNR {ev.ns_psnr:.2f} dB, IoU {ev.ns_iou:.3f}; before inpainting and fine-tuning "
                   f"PSNR {bf.ns_psnr:.2f} dB, IoU {bf.ns_iou:.3f}")
    f = res.files
    click.echo(f"object PLY  {f['object_ply']}")
    click.echo(f"pictures    {f['summary']} (a training view, the true object, before and after)")
    click.echo(f"            {f['object_picture']} (the object from four directions)")
    click.echo(f"            {f['debug']}/ (occlusion masks, inpainting grids, before and after fine-tuning)")
    click.echo(f"report      {f['report']}")


def _prune_demo(out_dir: str, seed: int | None, surface: str | None, overwrite: bool, progress) -> None:
    res = run_prune_demo(out_dir, seed=0 if seed is None else seed, surface=surface or "ant", overwrite=overwrite,
                         progress=progress)
    s = res.scores
    click.echo(f"pruned {res.input_count:,} -> {res.kept_count:,} Gaussians in {res.seconds:.1f} s: "
               f"far floaters removed {s['far']:.1%}, near-surface floaters removed {s['near']:.1%}, "
               f"object lost {s['object']:.2%}")
    for name, path in res.files.items():
        click.echo(f"  {name:<9} {path}")
