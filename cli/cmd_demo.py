"""``roodi-toolkit demo``: the README's main job on embedded data (no GPU, no downloads)."""

from __future__ import annotations

import click

from .common import overwrite_option, progress_factory, quiet_option


@click.command(epilog="Example:\n\n\b\n  roodi-toolkit demo demo-out\n  roodi-toolkit demo demo-out --overwrite --seed 3")
@click.argument("out_dir", type=click.Path(path_type=str), default="demo-out")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the generated cloud.")
@click.option("--surface", type=click.Choice(["ant", "sphere", "torus", "box"]), default="ant", show_default=True,
              help="The object's surface.")
@overwrite_option
@quiet_option
def demo(out_dir: str, seed: int, surface: str, overwrite: bool, quiet: bool) -> None:
    """Plant floaters around a generated object, prune them, and write the clouds and a picture to OUT_DIR."""
    from roodi_toolkit.demo import run_prune_demo

    res = run_prune_demo(out_dir, seed=seed, surface=surface, overwrite=overwrite, progress=progress_factory(quiet))
    s = res.scores
    click.echo(f"pruned {res.input_count:,} -> {res.kept_count:,} Gaussians in {res.seconds:.1f} s: "
               f"far floaters removed {s['far']:.1%}, near-surface floaters removed {s['near']:.1%}, "
               f"object lost {s['object']:.2%}")
    for name, path in res.files.items():
        click.echo(f"  {name:<9} {path}")
