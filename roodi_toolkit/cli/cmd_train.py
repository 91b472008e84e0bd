"""``roodi-toolkit train``: a 3DGS model of a whole scene, on the CPU, with MCMC densification."""

from __future__ import annotations

from typing import Any

import click

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.run.train import train_scene

from .common import overwrite_option, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import Options, SettingsCommand

EXAMPLE = """Example:

\b
  roodi-toolkit make-scene scenes/bedroom --preset bedroom --size 128x128
  roodi-toolkit train scenes/bedroom models/bedroom --iterations 3000
  roodi-toolkit train scenes/bedroom models/bedroom --iterations 6000 --resume   # continue a run
"""


TRAIN_SETTINGS = Options("roodi_toolkit.pipeline.train:TrainConfig", unset=True, only=(
    "iterations", "strategy.cap_max", "sh_degree", "init", "init_num_points", "random_background", "eval_every",
    "checkpoint_every", "seed"))
"""train's settings of TrainConfig: unset, the config's default, or with --resume the resumed run's."""


@click.command(cls=SettingsCommand, epilog=EXAMPLE)
@click.argument("data_dir", type=click.Path(path_type=str))
@click.argument("out_dir", type=click.Path(path_type=str))
@TRAIN_SETTINGS
@click.option("--downscale", type=click.FloatRange(1.0), default=1.0, show_default=True,
              help="Divide the image resolution by this factor.")
@click.option("--resume", is_flag=True, help="Continue from OUT_DIR/checkpoints/latest.pt (its settings are kept; "
              "--iterations may extend the run).")
@overwrite_option
@renderer_option
@quiet_option
def train(data_dir: str, out_dir: str, downscale: float, resume: bool, overwrite: bool, renderer: Any, quiet: bool,
          **settings: Any) -> None:
    """Train a 3DGS scene from posed images (COLMAP, Blender, or a nerfstudio / instant-ngp transforms.json) into
    OUT_DIR.

    Writes OUT_DIR/point_cloud/iteration_N/point_cloud.ply (Inria PLY), checkpoints/latest.pt, cfg.json,
    metrics.json, training.png and renders/ (held-out views beside the ground truth).
    """
    if resume and overwrite:
        raise ConfigError("--resume and --overwrite contradict each other; choose one")
    config = TRAIN_SETTINGS.config(settings)
    iterations = settings["iterations"]
    # the model folder is never half made (atomic): a signal or a full disk before the first checkpoint leaves none
    result = train_scene(data_dir, out_dir, config, downscale=downscale, resume=resume, overwrite=overwrite,
                         progress=progress_factory(quiet), iterations_override=iterations if resume else None,
                         renderer=renderer, atomic=True)
    ev = result.metrics
    figures = f", held-out PSNR {ev['psnr']:.2f} dB, SSIM {ev['ssim']:.3f}" if ev else ""
    click.echo(f"trained {result.iterations} iterations, {result.num_gaussians:,} Gaussians{figures} "
               f"({result.seconds_per_iteration * 1000:.0f} ms/iteration)")
    click.echo(f"model: {result.ply_path}")
