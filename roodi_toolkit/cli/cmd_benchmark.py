"""``roodi-toolkit benchmark``: the paper's Tables 1-2 on the generated scenes (ROODI, baselines, ablations)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import click

from roodi_toolkit.evaluate.benchmark import METHODS, PRESETS, SIZES, extract_config
from roodi_toolkit.run.benchmark import run_benchmark
from roodi_toolkit.plugins import load_plugin
from roodi_toolkit.synth.scene import make_benchmark_scene

from .common import overwrite_option, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import Options, SettingsCommand

EXAMPLE = """Example:

\b
  roodi-toolkit benchmark scenes/ bench/                       # 4 scenes, every method, sized for a CPU
  roodi-toolkit benchmark scenes/ bench/ --preset picnic --method full --method gaussian_grouping
  roodi-toolkit benchmark scenes_paper/ bench_paper/ --scale paper   # 200x200, 50+50 views, 30,000 steps
  roodi-toolkit benchmark scenes/ bench_occ/ --occluded --preset kitchen --inpainter opencv
"""


SIZE_SETTINGS = Options("roodi_toolkit.evaluate.benchmark:BenchmarkSize", only=("size", "iterations"), unset=True)
"""--size and --iterations: BenchmarkSize's settings; unset, the --scale's."""


@click.command(cls=SettingsCommand, epilog=EXAMPLE)
@click.argument("root", type=click.Path(path_type=str))
@click.argument("out_dir", type=click.Path(path_type=str))
@click.option("--preset", "presets", multiple=True, help="Scene preset to run (repeat; default all four).")
@click.option("--method", "methods", multiple=True,
              help="Method to run (repeat; default all): full, gaussian_grouping and gaussian_grouping_argmax (they "
                   "run no_two_stage too: they select from that model), feature_similarity, gaussian_grouping_shared, "
                   "no_two_stage, no_inpaint, no_prune, euclidean, paper_rule.")
@click.option("--seed", type=int, default=0, show_default=True, help="Scene and training seed.")
@click.option("--scale", type=click.Choice(["cpu", "cpu-large", "paper"]), default="cpu", show_default=True,
              help="cpu: 64x64, 32+8 views, 1,500 steps; cpu-large: 96x96, 40+12 views, 3,000 steps; paper: 200x200, "
                   "50+50 views, 30,000 steps.")
@SIZE_SETTINGS
@click.option("--occluded", is_flag=True,
              help="Run on the presets' occluded variants (ROOT/<preset>_occluded, make-scene --occluded) and also "
                   "score every method inside each test view's never-seen region.")
@Options("roodi_toolkit.pipeline.extract:ExtractConfig", only=("inpainter",))  # of full and the ablations that inpaint
@overwrite_option
@renderer_option
@quiet_option
def benchmark(root: str, out_dir: str, presets: tuple[str, ...], methods: tuple[str, ...], seed: int,
              scale: str, occluded: bool, inpainter: str, overwrite: bool, renderer: Any, quiet: bool,
              **sizes: Any) -> None:
    """Generate (or reuse) the preset scenes in ROOT, run ROODI, its baselines and ablations, and write
    OUT_DIR/results.md and results.json (the paper's Tables 1 and 2) and a picture grid per scene.

    Every stage is kept in OUT_DIR and reused on a re-run; --overwrite starts afresh (ROOT's scenes are always reused;
    remove a scene folder to regenerate it).
    """
    chosen = SIZE_SETTINGS.config(sizes, base=SIZES[scale])
    load_plugin("inpainters", inpainter)  # an unknown or broken --inpainter fails now, not after training
    config = replace(extract_config(chosen, seed), inpainter=inpainter)
    results = run_benchmark(root, out_dir, presets=presets or PRESETS, seed=seed, size=chosen,
                            methods=methods or tuple(METHODS), config=config, overwrite=overwrite,
                            progress=progress_factory(quiet), renderer=renderer, occluded=occluded,
                            make_scene=make_benchmark_scene)
    for m, scores in results["mean"].items():
        iou = "n/a" if scores["iou"] is None else f"{scores['iou']:.3f}"
        psnr = "n/a" if scores["psnr"] is None else f"{scores['psnr']:.2f}"
        region = ""
        if "ns_iou" in scores:
            ns_iou = "n/a" if scores["ns_iou"] is None else f"{scores['ns_iou']:.3f}"
            ns_psnr = "n/a" if scores["ns_psnr"] is None else f"{scores['ns_psnr']:.2f}"
            region = f"   never-seen region: PSNR {ns_psnr:>6}  IoU {ns_iou}"
        click.echo(f"{METHODS[m]:<45} PSNR {psnr:>6}  IoU {iou}{region}")
    for c in results["checks"]:
        click.echo(f"{'info' if c['met'] is None else 'met' if c['met'] else 'NOT met'}: {c['check']} "
                   f"({c['value']:+.3f})")
    if results.get("recomputed"):
        click.echo(f"rescored {len(results['recomputed'])} object(s) whose extraction or scene changed since the "
                   f"last run: {', '.join(sorted(results['recomputed']))}")
    click.echo(f"tables: {out_dir}/results.md, {out_dir}/results.json; pictures: {out_dir}/<preset>.png")
