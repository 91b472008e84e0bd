"""Tests of the benchmark-scene generator: camera consistency, occlusion, determinism, Blender round trip, CLI."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from roodi_toolkit.cli.main import main
from roodi_toolkit.io.dataset import load_dataset
from roodi_toolkit.errors import ConfigError, OutputError
from roodi_toolkit.io.files import read_image, read_json
from roodi_toolkit.synth.objects import PRESETS
from roodi_toolkit.synth.scene import (SceneSettings, build_scene, make_benchmark_scene, make_scene, scene_from_record,
                                       target_cameras, training_cameras)
from roodi_toolkit.synth.tracer import render_views

TINY = SceneSettings(width=48, height=40, train_views=6, test_views=3, supersample=1)


@pytest.fixture(scope="module")
def kitchen(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("kitchen") / "scene"
    make_scene(out, "kitchen", 3, settings=TINY)
    return out


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_scene_files_and_record(kitchen: Path) -> None:
    rec = read_json(kitchen / "scene.json")
    assert rec["preset"] == "kitchen" and rec["seed"] == 3
    assert 5 <= len(rec["objects"]) <= 20
    ids = [o["id"] for o in rec["objects"]]
    assert ids == list(range(1, len(ids) + 1))
    targets = [o for o in rec["objects"] if o["is_target"]]
    assert 3 <= len(targets) <= 4 and len(rec["targets"]) == len(targets)
    assert rec["settings"]["width"] == 48 and rec["settings"]["train_views"] == 6
    glossy = [o for o in rec["objects"] if any(m["reflectivity"] > 0 for m in o["materials"])]
    assert len(glossy) >= len(rec["objects"]) // 3  # kitchen: many reflective objects
    for t in rec["targets"]:
        assert (kitchen / t["path"] / "transforms_test.json").is_file()
    overview = read_image(kitchen / "overview.png")
    assert overview.ndim == 3 and overview.shape[0] > 40 and overview.shape[1] > 48


def test_blender_round_trip_through_the_loader(kitchen: Path) -> None:
    rec = read_json(kitchen / "scene.json")
    ds = load_dataset(kitchen)
    assert ds.format == "blender" and len(ds) == 6 and ds.splits == ["train"] * 6
    assert ds.images.shape == (6, 40, 48, 3) and ds.alphas is None
    assert ds.masks is not None and ds.depths is not None
    assert int(ds.masks.max()) <= len(rec["objects"]) and len(ds.masks.unique()) > 3
    np.testing.assert_allclose(ds.bounds, rec["scene_bounds"])
    for t in rec["targets"]:
        td = load_dataset(kitchen / t["path"])
        assert td.splits == ["test"] * 3 and td.alphas is not None and td.background == (1.0, 1.0, 1.0)
        assert set(td.masks.unique().tolist()) <= {0, t["id"]} and int(td.masks.max()) == t["id"]
        # alpha is the object's coverage: the mask sits inside it and white surrounds it
        assert bool((td.alphas[td.masks == t["id"]] > 0).all())
        empty = td.alphas == 0
        assert bool((td.images[empty] == 1.0).all())
        # test cameras differ from the training ones
        centres = np.stack([c.center for c in ds.cameras])
        for c in td.cameras:
            assert np.linalg.norm(centres - c.center, axis=1).min() > 0.05


def test_mesh_vertices_project_onto_their_object_mask(kitchen: Path) -> None:
    scene = scene_from_record(read_json(kitchen / "scene.json"))
    ds = load_dataset(kitchen)
    checked = in_frame = 0
    agree = 0
    for i, cam in enumerate(ds.cameras):
        mask, depth = ds.masks[i].numpy(), ds.depths[i].numpy()
        for obj in scene.objects:
            uv, z = cam.project(obj.vertices)
            px = np.floor(uv).astype(int)
            ok = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
            in_frame += int(ok.sum())
            px, z = px[ok], z[ok]
            d = depth[px[:, 1], px[:, 0]]
            # the pixel-centre ray hit a surface at the vertex's depth (3 %: a pixel here spans a few centimetres)
            visible = np.abs(d - z) < 0.03 * z
            checked += int(visible.sum())
            # a vertex on a silhouette may fall in a pixel whose centre sees the neighbour: accept the 3x3 block
            near = np.zeros(int(visible.sum()), dtype=bool)
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    yy = np.clip(px[visible, 1] + dy, 0, cam.height - 1)
                    xx = np.clip(px[visible, 0] + dx, 0, cam.width - 1)
                    near |= mask[yy, xx] == obj.id
            agree += int(near.sum())
    assert in_frame > 1000
    assert checked > 0.15 * in_frame, (checked, in_frame)  # wrong poses would make depth and projection disagree
    assert agree >= 0.98 * checked, (agree, checked)


def test_targets_are_partly_occluded_in_training_views(kitchen: Path) -> None:
    rec = read_json(kitchen / "scene.json")
    scene = scene_from_record(rec)
    ds = load_dataset(kitchen)
    for t in scene.targets:
        alone = render_views(scene, ds.cameras, object_ids=[t.id], with_ground=False, supersample=1)
        occluded_views = 0
        for i, r in enumerate(alone):
            visible = ds.masks[i].numpy() == t.id
            whole = r.ids == t.id
            assert not (visible & ~whole).any()  # what the scene shows of the target is part of the target alone
            if visible.sum() < 0.95 * whole.sum():
                occluded_views += 1
        assert occluded_views >= 1, t.name


def test_same_seed_identical_files_other_seed_other_layout(tmp_path: Path, kitchen: Path) -> None:
    make_scene(tmp_path / "again", "kitchen", 3, settings=TINY)
    assert _digest(tmp_path / "again") == _digest(kitchen)
    a, b = build_scene("kitchen", 3), build_scene("kitchen", 4)
    centres_a = np.stack([o.center for o in a.objects])
    centres_b = np.stack([o.center for o in b.objects])
    assert len(centres_a) != len(centres_b) or not np.allclose(centres_a, centres_b)


def test_the_benchmark_scene_is_the_generators_scene_at_the_benchmarks_size(tmp_path: Path) -> None:
    """make_benchmark_scene (what `benchmark` passes run_benchmark to generate a missing scene) writes the scene
    make_scene writes with the size's image side, view counts and anti-aliasing."""
    from roodi_toolkit.evaluate.benchmark import BenchmarkSize

    size = BenchmarkSize(size=24, train_views=3, test_views=2, iterations=1, init_points=1, cap_max=1, supersample=1)
    rec = make_benchmark_scene(tmp_path / "bench", "picnic", 2, size, occluded=True)
    make_scene(tmp_path / "gen", "picnic", 2, settings=SceneSettings(width=24, height=24, train_views=3, test_views=2,
                                                                      supersample=1, occluded=True))
    assert rec["settings"] == read_json(tmp_path / "gen" / "scene.json")["settings"]
    assert rec["settings"]["occluded"] and rec["settings"]["width"] == rec["settings"]["height"] == 24
    assert _digest(tmp_path / "bench") == _digest(tmp_path / "gen")


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_presets_build_and_render(preset: str) -> None:
    scene = build_scene(preset, 11)
    assert 5 <= len(scene.objects) <= 20 and 3 <= len(scene.targets) <= 4
    assert all(o.vertices[:, 2].min() > -1e-6 for o in scene.objects)  # nothing sinks into the ground
    cams = training_cameras(scene, 2, 24, 20)
    (r,) = render_views(scene, cams[:1], supersample=1)
    assert r.rgb.shape == (20, 24, 3) and r.rgb.dtype == np.float32
    assert len(np.unique(r.ids)) >= 3 and (r.depth[-1] > 0).all()  # the ground fills the bottom of every view
    if preset == "picnic":
        assert PRESETS[preset].outdoor and scene.lights[0].kind == "directional"


def test_shadows_darken_the_ground() -> None:
    scene = build_scene("picnic", 0)
    cams = training_cameras(scene, 1, 64, 64)
    with_objects = render_views(scene, cams, supersample=1)[0]
    scene.objects = []
    only_ground = render_views(scene, cams, supersample=1)[0]
    ground = with_objects.ids == 0
    darker = (with_objects.rgb.mean(axis=2) < only_ground.rgb.mean(axis=2) - 0.1) & ground
    assert darker.sum() > 20  # cast shadows on the grass


def _extent(cam, vertices: np.ndarray) -> float:
    """Fraction of the image width the projected vertices span."""
    uv, _ = cam.project(vertices)
    return float(np.ptp(uv[:, 0]) / cam.width)


def test_test_cameras_scene_framing_matches_training_scale_and_object_framing_fills_the_view() -> None:
    scene = build_scene("kitchen", 4)
    target = scene.targets[0]
    centre = (target.vertices.min(axis=0) + target.vertices.max(axis=0)) / 2
    train = training_cameras(scene, 12, 64, 64)
    near = target_cameras(scene, target, 12, 64, 64, framing="object")
    far = target_cameras(scene, target, 12, 64, 64)  # the paper's protocol is the default
    train_dist = [np.linalg.norm(c.center - centre) for c in train]
    far_dist = [np.linalg.norm(c.center - centre) for c in far]
    # at the training cameras' range, aimed at the target (it projects to the middle), not at training positions
    assert 0.6 * min(train_dist) < np.median(far_dist) < 1.5 * max(train_dist)
    for cam in far:
        uv, z = cam.project(centre[None])
        assert z[0] > 0 and np.abs(uv[0] - 32).max() < 1.0
    assert min(np.linalg.norm(a.center - b.center) for a in far for b in train) > 1e-3
    # the object is as large as in training with scene framing, and fills the view in close-ups
    train_size = np.median([_extent(c, target.vertices) for c in train])
    assert 0.5 < np.median([_extent(c, target.vertices) for c in far]) / train_size < 2.0
    assert np.median([_extent(c, target.vertices) for c in near]) > 0.5
    with pytest.raises(ConfigError, match="framing"):
        target_cameras(scene, target, 2, 64, 64, framing="tight")
    with pytest.raises(ConfigError, match="test_framing"):
        SceneSettings(test_framing="tight")


def test_settings_and_preset_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="preset"):
        build_scene("garage", 0)
    with pytest.raises(ConfigError, match="n_objects"):
        SceneSettings(n_objects=30)
    with pytest.raises(ConfigError, match="width must be"):
        SceneSettings(width=4)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("keep")
    with pytest.raises(OutputError, match="overwrite"):
        make_scene(tmp_path / "full", "bedroom", 0, settings=TINY)


def test_cli_make_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"
    args = ["make-scene", str(out), "--preset", "picnic", "--seed", "2", "--size", "32x24", "--train-views", "3",
            "--test-views", "2", "--targets", "3", "--objects", "6", "--supersample", "1", "-q"]
    assert main(args) == 0
    rec = read_json(out / "scene.json")
    assert len(rec["targets"]) == 3 and len(rec["objects"]) == 6
    assert read_image(out / "train" / "r_000.png").shape == (24, 32, 3)
    assert main(args) == 1
    assert "overwrite" in capsys.readouterr().err
    assert main(args + ["--overwrite"]) == 0
    assert main(["make-scene", str(out), "--preset", "garage"]) == 2


@pytest.mark.slow
@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_full_size_scene(tmp_path: Path, preset: str) -> None:
    rec = make_scene(tmp_path / preset, preset, 0)
    ds = load_dataset(tmp_path / preset)
    assert ds.images.shape == (50, 200, 200, 3)
    for t in rec["targets"]:
        assert len(load_dataset(tmp_path / preset / t["path"])) == 50


@pytest.mark.parametrize("kwargs,message", [
    ({"width": 7}, "width must be a whole number in [8, 8192], got 7"),
    ({"height": 8193}, "height must be a whole number in [8, 8192], got 8193"),
    ({"train_views": 0}, "train_views must be a whole number in [1, 1000]"),
    ({"test_views": 1001}, "test_views must be a whole number in [1, 1000]"),
    ({"fov_x_deg": 5.0}, "fov_x_deg must be a finite number in [10, 120]"),
    ({"supersample": 5}, "supersample must be a whole number in [1, 4]"),
    ({"n_targets": 5}, "n_targets must be a whole number in [1, 4] or None"),
    ({"n_objects": 4}, "n_objects must be a whole number in [5, 20] or None"),
    ({"test_framing": "far"}, "test_framing must be one of scene, object"),
    ({"occluded": 1}, "occluded must be true or false"),
])
def test_scene_settings_outside_their_declared_range_are_refused_by_name(kwargs, message):
    with pytest.raises(ConfigError) as err:
        SceneSettings(**kwargs)
    assert str(err.value).startswith(message), str(err.value)
    assert "Attributes:" in SceneSettings.__doc__ and "width: Image size WIDTHxHEIGHT" in SceneSettings.__doc__
