"""``roodi-toolkit train``: a 3DGS model of a whole scene, on the CPU, with MCMC densification."""

from __future__ import annotations

from typing import Any

import click

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.pipeline.train import TrainConfig, config_with
from roodi_toolkit.run.train import train_scene

from .common import overwrite_option, progress_factory, quiet_option
from .renderer_option import renderer_option

EXAMPLE = """Example:

\b
  roodi-toolkit make-scene scenes/bedroom --preset bedroom --size 128x128
  roodi-toolkit train scenes/bedroom models/bedroom --iterations 3000
  roodi-toolkit train scenes/bedroom models/bedroom --iterations 6000 --resume   # continue a run
"""


@click.command(epilog=EXAMPLE)
@click.argument("data_dir", type=click.Path(path_type=str))
@click.argument("out_dir", type=click.Path(path_type=str))
@click.option("--iterations", type=click.IntRange(1), default=None, help="Optimisation steps [default: 3000].")
@click.option("--cap-max", type=click.IntRange(1), default=None, help="Most Gaussians MCMC may grow to [60000].")
@click.option("--sh-degree", type=click.IntRange(0, 3), default=None, help="Largest SH degree [3].")
@click.option("--downscale", type=click.FloatRange(1.0), default=1.0, show_default=True,
              help="Divide the image resolution by this factor.")
@click.option("--init", type=click.Choice(["auto", "points", "random", "depth"]), default=None,
              help="Initial Gaussians: sparse points (COLMAP), random in the scene box, or lifted from the views' "
              "depth maps (datasets with depth, e.g. make-scene) [auto: points if any, else random].")
@click.option("--init-points", type=click.IntRange(4), default=None,
              help="Random initialisation size; sparse SfM points fewer than this are topped up to it [20000].")
@click.option("--random-background/--fixed-background", default=None,
              help="Render on a random colour each step (images with alpha are composited on it; opaque photos "
              "then teach every pixel to be covered), or on the dataset's background [default: random when the "
              "images have alpha, as 3DGS trainers do; cfg.json records the choice].")
@click.option("--eval-every", type=click.IntRange(0), default=None, help="Evaluate on held-out views this often.")
@click.option("--checkpoint-every", type=click.IntRange(1), default=None, help="Checkpoint this often [250].")
@click.option("--seed", type=int, default=None, help="Random seed [0].")
@click.option("--resume", is_flag=True, help="Continue from OUT_DIR/checkpoints/latest.pt (its settings are kept; "
              "--iterations may extend the run).")
@overwrite_option
@renderer_option
@quiet_option
def train(data_dir: str, out_dir: str, iterations: int | None, cap_max: int | None, sh_degree: int | None,
          downscale: float, init: str | None, init_points: int | None, random_background: bool | None,
          eval_every: int | None, checkpoint_every: int | None, seed: int | None, resume: bool, overwrite: bool,
          renderer: Any, quiet: bool) -> None:
    """Train a 3DGS scene from posed images (COLMAP, Blender, or a nerfstudio / instant-ngp transforms.json) into
    OUT_DIR.

    Writes OUT_DIR/point_cloud/iteration_N/point_cloud.ply (Inria PLY), checkpoints/latest.pt, cfg.json,
    metrics.json, training.png and renders/ (held-out views beside the ground truth).
    """
    if resume and overwrite:
        raise ConfigError("--resume and --overwrite contradict each other; choose one")
    config = config_with(TrainConfig(), iterations=iterations, cap_max=cap_max, sh_degree=sh_degree, init=init,
                         init_num_points=init_points, random_background=random_background,
                         eval_every=eval_every, checkpoint_every=checkpoint_every, seed=seed)
    # the model folder is never half made (atomic): a signal or a full disk before the first checkpoint leaves none
    result = train_scene(data_dir, out_dir, config, downscale=downscale, resume=resume, overwrite=overwrite,
                         progress=progress_factory(quiet), iterations_override=iterations if resume else None,
                         renderer=renderer, atomic=True)
    ev = result.metrics
    figures = f", held-out PSNR {ev['psnr']:.2f} dB, SSIM {ev['ssim']:.3f}" if ev else ""
    click.echo(f"trained {result.iterations} iterations, {result.num_gaussians:,} Gaussians{figures} "
               f"({result.seconds_per_iteration * 1000:.0f} ms/iteration)")
    click.echo(f"model: {result.ply_path}")
