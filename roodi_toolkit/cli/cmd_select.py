"""``roodi-toolkit select``: one object's Gaussians from a distilled scene, outliers pruned (ROODI Fig. 2d)."""

from __future__ import annotations

from typing import Any

import click

from roodi_toolkit.run.select import run_select

from .common import overwrite_option, progress_factory, quiet_option
from .renderer_option import renderer_option
from .settings import Options, SettingsCommand

EXAMPLE = """Examples:

\b
  roodi-toolkit distill models/bedroom scenes/bedroom dist/bedroom
  roodi-toolkit select dist/bedroom --object 2 ball.ply
  roodi-toolkit select dist/bedroom --object 1 chair.ply --threshold 0.5 --no-prune
"""


SELECT_SETTINGS = Options("roodi_toolkit.pipeline.extract:ExtractConfig", only=("threshold", "prune"))
"""select's settings: extract's selection threshold and pruning switch (ExtractConfig's)."""


@click.command(cls=SettingsCommand, epilog=EXAMPLE)
@click.argument("distill_dir", type=click.Path(path_type=str))
@click.argument("output_ply", metavar="OUT.ply", type=click.Path(path_type=str))
@click.option("--object", "object_id", type=click.IntRange(0), required=True,
              help="Class id of the object (its instance id in the masks; 1 for click/binary masks).")
@SELECT_SETTINGS
@click.option("--picture", type=click.Path(path_type=str), default=None,
              help="Where to write the picture of rendered probabilities beside the masks [OUT.png].")
@overwrite_option
@renderer_option
@quiet_option
def select(distill_dir: str, output_ply: str, object_id: int, threshold: float, prune: bool, picture: str | None,
           overwrite: bool, renderer: Any, quiet: bool) -> None:
    """Write the Gaussians of object --object of the distillation DISTILL_DIR (a roodi-toolkit distill output) to
    OUT.ply; the scene is read from the model file the distillation names."""
    summary = run_select(distill_dir, object_id, output_ply, threshold=threshold, prune=prune,
                         picture=picture, overwrite=overwrite, progress=progress_factory(quiet), renderer=renderer)
    pruned = f", {summary['pruned']:,} pruned as outliers" if summary["pruned"] is not None else ""
    name = f" ({summary['label']})" if summary.get("label") else ""
    click.echo(f"object {object_id}{name}: {summary['selected']:,} of {summary['num_gaussians']:,} Gaussians above "
               f"{threshold}{pruned}; wrote {summary['kept']:,} to {output_ply}")
    if summary.get("picture"):
        click.echo(f"picture: {summary['picture']}")
