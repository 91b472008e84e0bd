"""``roodi-toolkit demo``: the README's main job on generated data (no GPU, no downloads): extract one object."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import click

from roodi_toolkit.pipeline.train import config_with
from roodi_toolkit.plugins import load_plugin
from roodi_toolkit.synth.demo import ExtractDemoConfig, run_extract_demo, run_prune_demo
from roodi_toolkit.synth.scene import SceneSettings

from .common import overwrite_option, parse_size, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import Options, SettingsCommand

PRESET_NAMES = ("bedroom", "kitchen", "livingroom", "picnic")
SURFACES = ("ant", "sphere", "torus", "box")

EXAMPLE = """Example:

\b
  roodi-toolkit demo demo-out                       # about 5 minutes on 2 cores
  roodi-toolkit demo demo-out --overwrite --preset livingroom --seed 5
  roodi-toolkit demo small --size 64 --train-views 24 --iterations 800 --max-gaussians 8000
  roodi-toolkit demo prune-out --prune-only         # the planted-floater pruning demo (seconds)
"""

# parameter -> flag of the demo's own options that only the extraction demo takes (None when not given: the
# library's default); the options of DEMO_SETTINGS and DEMO_REFINE_SETTINGS are the extraction demo's too
EXTRACT_ONLY = {"preset": "--preset", "object_id": "--object", "size_text": "--size", "train_views": "--train-views",
                "test_views": "--test-views", "max_gaussians": "--max-gaussians",
                "occluded": "--occluded/--no-occluded", "train_seed": "--train-seed"}


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


def _scores(ev) -> str:
    lpips = f"{ev.lpips:.3f}" if ev.lpips is not None else "unavailable (no local weights)"
    return f"PSNR {ev.psnr:.2f} dB, SSIM {ev.ssim:.3f}, LPIPS {lpips}, IoU {ev.iou:.3f}"


DEMO_SETTINGS = Options("roodi_toolkit.synth.demo:ExtractDemoConfig", within="extract", unset=True,
                        only=("train.iterations", "distill.iterations", "inpainter"))
"""The demo's settings of its ExtractConfig (--iterations, --distill-iterations, --inpainter); unset: the demo's own
(not given, --prune-only may go with them)."""

DEMO_REFINE_SETTINGS = Options("roodi_toolkit.synth.demo:ExtractDemoConfig", within="extract", unset=True,
                               only=("finetune.iterations", "occlusion.size"))
"""The demo's settings of its refinement (--finetune-iterations, --view-size), unset as DEMO_SETTINGS' (a second set
only to keep them where ``--help`` lists them)."""


def _extract_only(params: dict[str, Any]) -> list[str]:
    """Return the flags given that only the extraction demo takes, in ``--help``'s order."""
    flags = dict(EXTRACT_ONLY)
    flags.update((o.param, o.option) for o in DEMO_SETTINGS.offered() + DEMO_REFINE_SETTINGS.offered())
    order = [p.name for p in click.get_current_context().command.params]
    return [flags[name] for name in sorted(flags, key=order.index) if params[name] is not None]


@click.command(cls=SettingsCommand, epilog=EXAMPLE)
@click.argument("out_dir", type=click.Path(path_type=str), default="demo-out")
@click.option("--preset", type=click.Choice(PRESET_NAMES), default=None, help="Generated scene type [kitchen].")
@click.option("--seed", type=int, default=None,
              help="Seed of the generated scene [2] (with --prune-only: of the generated cloud [0]).")
@click.option("--object", "object_id", type=int, default=None,
              help="Instance id of the target to extract [the target other objects hide most].")
@click.option("--size", "size_text", default=None, help="Image size WIDTHxHEIGHT (or one number) [128x128].")
@click.option("--train-views", type=click.IntRange(1, 1000), default=None, help="Views of the full scene [50].")
@click.option("--test-views", type=click.IntRange(1, 1000), default=None,
              help="Views of the target alone, used for scoring [12].")
@DEMO_SETTINGS
@click.option("--train-seed", type=click.IntRange(0), default=None,
              help="Seed of the scene training [0]; the scene stays the same (--seed). Runs with other seeds show "
                   "how much the figures move from run to run (docs/benchmark.md, \"Run to run\").")
@click.option("--max-gaussians", type=click.IntRange(2), default=None,
              help="Most Gaussians the scene may grow to; it starts from half as many [30000].")
@DEMO_REFINE_SETTINGS
@click.option("--occluded/--no-occluded", default=None,
              help="The preset's occluded variant (make-scene --occluded): the target stands in a wrap that hides "
                   "part of it from every training view [occluded]; --no-occluded: the plain preset.")
@click.option("--prune-only", is_flag=True, help="Run the planted-floater pruning demo instead (seconds).")
@click.option("--surface", type=click.Choice(SURFACES), default=None,
              help="With --prune-only: the generated object's surface [ant].")
@overwrite_option
@renderer_option
@quiet_option
def demo(out_dir: str, preset: str | None, seed: int | None, object_id: int | None, size_text: str | None,
         train_views: int | None, test_views: int | None, train_seed: int | None, max_gaussians: int | None,
         occluded: bool | None, prune_only: bool, surface: str | None, overwrite: bool, renderer: Any, quiet: bool,
         **settings: Any) -> None:
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
    width, height = parse_size(size_text) if size_text is not None else (base.scene.width, base.scene.height)
    scene = SceneSettings(width=width, height=height, train_views=train_views or base.scene.train_views,
                          test_views=test_views or base.scene.test_views,
                          occluded=base.scene.occluded if occluded is None else occluded)
    ex = DEMO_REFINE_SETTINGS.config(params, base=DEMO_SETTINGS.config(params, base=base.extract))
    train = config_with(ex.train, cap_max=max_gaussians, seed=train_seed,
                        init_num_points=None if max_gaussians is None else max(1, max_gaussians // 2))
    extract = replace(ex, train=train)
    if extract.inpaint:  # an unknown or broken --inpainter fails now, not after the scene has been trained
        load_plugin("inpainters", extract.inpainter)
    config = replace(base, preset=preset or base.preset, seed=base.seed if seed is None else seed,
                     object_id=object_id, scene=scene, extract=extract)
    res = run_extract_demo(out_dir, config, overwrite=overwrite, progress=progress, renderer=renderer)

    st, g = res.stages, res.gaussians
    psnr = f", held-out PSNR {res.scene_psnr:.2f} dB" if res.scene_psnr is not None else ""
    click.echo(f"extracted {res.object_name} (object {res.object_id}) from a generated {config.preset} scene "
               f"(seed {config.seed}, {width}x{height}, {scene.train_views} views) in {_duration(res.seconds)}; "
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
