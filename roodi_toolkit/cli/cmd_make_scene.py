"""``roodi-toolkit make-scene``: generate a multi-object benchmark scene in the Blender format."""

from __future__ import annotations

import click

from roodi_toolkit.synth.scene import SceneSettings, make_scene as run

from .common import overwrite_option, parse_size, progress_factory, quiet_option

PRESET_NAMES = ("bedroom", "kitchen", "livingroom", "picnic")


@click.command("make-scene")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--preset", type=click.Choice(PRESET_NAMES), default="bedroom", show_default=True,
              help="Scene type: bedroom (general), kitchen (glossy), livingroom (heavy overlap), picnic (sun, shadows).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed; the same seed gives identical files.")
@click.option("--size", "size_text", default="200x200", show_default=True, help="Image size WIDTHxHEIGHT (or one number).")
@click.option("--train-views", type=click.IntRange(1, 1000), default=50, show_default=True,
              help="Views of the full scene.")
@click.option("--test-views", type=click.IntRange(1, 1000), default=50, show_default=True,
              help="Views of each target alone.")
@click.option("--objects", "n_objects", type=click.IntRange(5, 20), default=None,
              help="Number of objects (default: drawn from the preset's range).")
@click.option("--targets", "n_targets", type=click.IntRange(1, 4), default=None,
              help="Number of targets (default: 3 or 4).")
@click.option("--supersample", type=click.IntRange(1, 4), default=2, show_default=True,
              help="Anti-aliasing rays per pixel along each axis (masks and depth always use the pixel centre).")
@click.option("--test-framing", type=click.Choice(("scene", "object")), default="scene", show_default=True,
              help="Test cameras: 'scene' = at the training cameras' distance, aimed at the target (the paper's "
                   "protocol); 'object' = close-ups in which the target fills the frame.")
@click.option("--occluded", is_flag=True,
              help="The occluded variant: 4 targets (default), each standing in a wrap that touches it (a box or "
                   "sleeve open at the top, or a bowl) and hides its lower part from every training view; writes "
                   "the never-seen masks.")
@click.option("--never-seen", is_flag=True,
              help="Write each target's never-seen masks (test-view pixels no training view sees) and their share "
                   "(always on with --occluded).")
@overwrite_option
@quiet_option
def make_scene(out_dir: str, preset: str, seed: int, size_text: str, train_views: int, test_views: int,
               n_objects: int | None, n_targets: int | None, supersample: int, test_framing: str, occluded: bool,
               never_seen: bool, overwrite: bool, quiet: bool) -> None:
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
    width, height = parse_size(size_text)
    settings = SceneSettings(width=width, height=height, train_views=train_views, test_views=test_views,
                             supersample=supersample, n_objects=n_objects, n_targets=n_targets,
                             test_framing=test_framing, occluded=occluded, never_seen=never_seen)
    record = run(out_dir, preset, seed, settings=settings, overwrite=overwrite, progress=progress_factory(quiet))
    targets = ", ".join(f"{t['id']}:{t['name']}" for t in record["targets"])
    if not quiet:
        click.echo(f"wrote {out_dir}: {len(record['objects'])} objects, targets {targets}, "
                   f"{train_views} training views, {test_views} test views per target "
                   f"({record['_seconds']:.1f} s)")
        shares = [t for t in record["targets"] if "never_seen_share" in t]
        if shares:
            click.echo("never seen in training (share of each target's test-view pixels): " + ", ".join(
                f"{t['name']} {100 * t['never_seen_share']:.1f}%" for t in shares))
