"""``roodi-toolkit make-scene``: generate a multi-object benchmark scene in the Blender format."""

from __future__ import annotations

from typing import Any

import click

from roodi_toolkit.synth.objects import PRESETS
from roodi_toolkit.synth.scene import SceneSettings, make_scene as run

from .common import overwrite_option, progress_factory, quiet_option
from .settings import Options

PRESET_NAMES = tuple(PRESETS)

SCENE_SETTINGS = Options(SceneSettings)
"""The generator's settings (--size, --train-views, --test-views, --objects, --targets, --supersample,
--test-framing, --occluded, --never-seen): every command-line setting of SceneSettings."""


@click.command("make-scene")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--preset", type=click.Choice(PRESET_NAMES), default="bedroom", show_default=True,
              help="Scene type: bedroom (general), kitchen (glossy), livingroom (heavy overlap), picnic (sun, shadows).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed; the same seed gives identical files.")
@SCENE_SETTINGS
@overwrite_option
@quiet_option
def make_scene(out_dir: str, preset: str, seed: int, overwrite: bool, quiet: bool, **values: Any) -> None:
    """Write a cluttered scene with 3-4 target objects, rendered by ray casting meshes, to OUT_DIR.

    \b
    OUT_DIR/transforms_train.json   full-scene views with instance masks and depth
    OUT_DIR/targets/*/transforms_test.json   each target alone (RGBA on white)
    OUT_DIR/scene.json, OUT_DIR/overview.png
    OUT_DIR/targets/*/test/never_seen   with --occluded / --never-seen: 255 where no training view sees the target

    \b
    Example:
      roodi-toolkit make-scene scenes/kitchen0 --preset kitchen --seed 0
      roodi-toolkit make-scene scenes/kitchen0_occ --preset kitchen --occluded --size 64
    """
    settings = SCENE_SETTINGS.config(values)
    record = run(out_dir, preset, seed, settings=settings, overwrite=overwrite, progress=progress_factory(quiet))
    targets = ", ".join(f"{t['id']}:{t['name']}" for t in record["targets"])
    if not quiet:
        click.echo(f"wrote {out_dir}: {len(record['objects'])} objects, targets {targets}, "
                   f"{settings.train_views} training views, {settings.test_views} test views per target "
                   f"({record['_seconds']:.1f} s)")
        shares = [t for t in record["targets"] if "never_seen_share" in t]
        if shares:
            click.echo("never seen in training (share of each target's test-view pixels): " + ", ".join(
                f"{t['name']} {100 * t['never_seen_share']:.1f}%" for t in shares))
