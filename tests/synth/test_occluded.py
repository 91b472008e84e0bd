"""Tests of the occluded scene variant (issue 22): wraps, never-seen masks and their share, determinism, and that the
plain presets are unchanged."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.cli.main import main
from roodi_toolkit.errors import ConfigError
from roodi_toolkit.io.files import read_image, read_json
from roodi_toolkit.synth.objects import PRESETS, Material, SceneObject, box
from roodi_toolkit.synth.scene import (NEVER_SEEN_DIR, Scene, SceneSettings, build_scene, make_scene,
                                       scene_from_record, target_cameras, training_cameras)
from roodi_toolkit.synth.tracer import _Tracer, render_views
from roodi_toolkit.synth.visibility import VISIBILITY_TOLERANCE, never_seen_masks, seen_by_any
from roodi_toolkit.synth.wraps import WRAP_GAP, WRAP_KINDS, WRAPPABLE

# make-scene kitchen, seed 3, 48x40, 6 + 3 views, supersample 1, as made by commit 39c5420 (before the occluded
# variant existed): sha256 over the JSON files (paths and content, floats rounded to 5 decimals) and the sum of the
# pixel values of each kind of image. Not the files' bytes: those differ between CPUs (the renders' float rounding;
# the bytes recorded on the first machine did not match 39c5420's own output on an AMD EPYC, where these were taken)
PLAIN_KITCHEN_JSON = "9a6b0d2ffe5548b8e2c84d92cdf35f7198dde64cdc7e6feab04b491a48b14517"
PLAIN_KITCHEN_PIXELS = {"overview": 16478675, "masks": 13411, "images": 20188432, "depth": 299540149}
SMOOTH_ROUND = ("vase", "apple", "ball", "bottle", "glass")  # wrapped without pockets between object and wall
SMALL = SceneSettings(width=64, height=64, train_views=16, test_views=4, supersample=1, occluded=True)


def _rounded(value: object) -> object:
    if isinstance(value, float):
        return round(value, 5)
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value


def _fingerprint(root: Path) -> tuple[str, dict[str, int]]:
    """Return the JSON digest and the pixel sums of a scene folder (see PLAIN_KITCHEN_JSON)."""
    digest, sums = hashlib.sha256(), {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        if p.suffix == ".json":
            digest.update(rel.encode())
            digest.update(json.dumps(_rounded(read_json(p)), sort_keys=True).encode())
        elif p.is_file():
            kind = "masks" if "/masks/" in rel else "depth" if "/depth/" in rel else "images" if "/" in rel else p.stem
            sums[kind] = sums.get(kind, 0) + int(np.asarray(read_image(p), dtype=np.float64).sum())
    return digest.hexdigest(), sums


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def kitchen_occ(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("occ") / "kitchen"
    make_scene(out, "kitchen", 0, settings=SMALL)
    return out


# ------------------------------------------------------------------------------------------- visibility by hand


def _box_scene() -> Scene:
    """A 0.2 m cube (target, id 1) at the origin and a wall (id 2) 0.5 m to its -x side, on a ground disc."""
    mat = Material(color=(0.5, 0.5, 0.5))
    cube = SceneObject(1, "cube_1", "crate", [box((0.2, 0.2, 0.2), mat)], is_target=True)
    wall = SceneObject(2, "wall_1", "crate", [box((0.02, 1.0, 0.6), mat, at=(-0.5, 0.0, 0.0))])
    ground = build_scene("kitchen", 0).ground
    return Scene("kitchen", 0, [cube, wall], ground, [], (0.3, 0.3, 0.3), ((1, 1, 1), (1, 1, 1)))


def _camera(eye: tuple[float, float, float], aim: tuple[float, float, float] = (0, 0, 0.1)) -> Camera:
    return Camera(look_at(np.array(eye, float), np.array(aim, float)), intrinsics_from_fov(math.radians(50), 64, 64),
                  64, 64)


def test_seen_by_any_on_points_one_can_reason_about() -> None:
    scene = _box_scene()
    tracer = _Tracer(scene, None, True)
    front = _camera((2.0, 0.0, 0.1))  # on +x, looking at the cube
    behind_wall = _camera((-1.5, 0.0, 0.1))  # on -x: the wall stands between it and the cube
    points = np.array([[0.1, 0.0, 0.1],    # the cube's +x face, facing the front camera: seen
                       [-0.1, 0.0, 0.1],   # its -x face: the cube hides it from the front, the wall from behind
                       [0.0, 0.0, 0.2],    # its top: the cameras are level with its middle, the top is edge-on
                       [0.1, 0.0, 0.05]])  # +x face, lower: seen
    seen = seen_by_any(tracer, points, [front, behind_wall])
    assert seen.tolist() == [True, False, False, True]
    # without the wall the camera behind sees the -x face
    alone = _Tracer(scene, [1], True)
    assert seen_by_any(alone, points[1:2], [behind_wall]).tolist() == [True]
    # a camera that looks away sees nothing (the point is behind it)
    away = _camera((2.0, 0.0, 0.1), aim=(4.0, 0.0, 0.1))
    assert not seen_by_any(tracer, points, [away]).any()
    assert VISIBILITY_TOLERANCE < WRAP_GAP  # a wrap's wall in front of a point is never taken for the point


def test_never_seen_masks_of_a_test_view() -> None:
    scene = _box_scene()
    front = _camera((2.0, 0.0, 0.6))  # sees the cube's top and +x face
    side = _camera((0.0, 1.2, 0.9))  # a test view of the top and the +y face
    r = render_views(scene, [side], object_ids=[1], with_ground=False, supersample=1)[0]
    on = r.ids == 1
    mask = never_seen_masks(scene, 1, [side], [r], [front])[0]
    assert on.sum() > 100 and not (mask & ~on).any()
    from roodi_toolkit.synth.visibility import surface_points

    p = surface_points(side, r.depth)
    face_y = on & (p[..., 1] > 0.1 - 1e-3)  # pixels on the +y face: the front camera sees it edge-on at best
    top = on & (p[..., 2] > 0.2 - 1e-3)
    assert face_y.sum() > 20 and top.sum() > 20
    assert mask[face_y & ~top].mean() > 0.95
    assert not mask[top & ~face_y].any()
    # a training camera where the test camera is sees everything the test view shows
    assert not never_seen_masks(scene, 1, [side], [r], [front, side])[0].any()
    # but not what the wall hides: the object-alone view from behind the wall shows the -x face, which even a
    # training camera at the same spot cannot see through the wall
    back = _camera((-1.5, 0.0, 0.25))
    rb = render_views(scene, [back], object_ids=[1], with_ground=False, supersample=1)[0]
    mb = never_seen_masks(scene, 1, [back], [rb], [back])[0]
    assert (rb.ids == 1).sum() > 50 and mb[rb.ids == 1].all()


# ---------------------------------------------------------------------------------------------- occluded scenes


def test_occluded_scene_shares_and_files(kitchen_occ: Path) -> None:
    rec = read_json(kitchen_occ / "scene.json")
    assert rec["settings"]["occluded"] is True and "never_seen" in rec
    assert len(rec["targets"]) == 4
    for t in rec["targets"]:
        assert t["never_seen_share"] >= 0.10, t
        frames = read_json(kitchen_occ / t["path"] / "transforms_test.json")["frames"]
        masks = [read_image(kitchen_occ / t["path"] / f["never_seen_path"]) > 127 for f in frames]
        ids = [read_image(kitchen_occ / t["path"] / f["mask_path"]) == t["id"] for f in frames]
        assert sum(int(m.sum()) for m in masks) == t["never_seen_pixels"] > 0
        assert all(not (m & ~i).any() for m, i in zip(masks, ids))  # only on the target
        assert t["never_seen"] == NEVER_SEEN_DIR
    # wraps: one per target, ids right after the targets', each touching its target
    scene = scene_from_record(rec)
    n_t = len(scene.targets)
    for t in scene.targets:
        wrap = scene.object(t.id + n_t)
        assert wrap.kind in WRAP_KINDS and not wrap.is_target
        gap = np.linalg.norm(wrap.center[:2] - t.center[:2])
        assert gap < 0.05
        assert wrap.bounds[1, 2] < t.bounds[1, 2]  # lower than the target: its top stays in view


def test_hidden_and_seen_points_of_an_occluded_target(kitchen_occ: Path) -> None:
    rec = read_json(kitchen_occ / "scene.json")
    scene = scene_from_record(rec)
    cams = training_cameras(scene, SMALL.train_views, SMALL.width, SMALL.height)
    tracer = _Tracer(scene, None, True)
    checked = 0
    for t in scene.targets:
        tc = target_cameras(scene, t, 2, 96, 96)
        r = render_views(scene, tc, object_ids=[t.id], with_ground=False, supersample=1)
        masks = never_seen_masks(scene, t.id, tc, r, cams, tracer=tracer)
        from roodi_toolkit.synth.visibility import surface_points

        wrap_top = scene.object(t.id + len(scene.targets)).bounds[1, 2]
        for cam, rr, m in zip(tc, r, masks):
            on = rr.ids == t.id
            z = surface_points(cam, rr.depth)[..., 2]
            low = on & (z < 0.3 * wrap_top)  # deep inside the wrap: hidden from every training camera
            high = on & (z >= np.quantile(z[on], 0.9)) & (z > wrap_top)  # its highest pixels: seen
            assert low.any(), t.name
            if t.kind in SMOOTH_ROUND:
                checked += 1
                assert m[low].all(), t.name  # no pocket between target and wrap: surely hidden
            else:  # a handle makes a pocket in the wrap's hull that a steep camera can look down into
                assert m[low].mean() > 0.6, t.name
            assert high.any() and not m[high].all(), t.name
        assert not m[z >= t.bounds[1, 2] - 1e-3].any()  # the very top of the target is seen
    assert checked >= 2  # kitchen seed 0 has a vase in a sleeve and an apple in a bowl


@pytest.mark.parametrize("preset", ["bedroom", "livingroom", "picnic"])
def test_other_presets_reach_the_share(tmp_path: Path, preset: str) -> None:
    rec = make_scene(tmp_path / preset, preset, 0, settings=SMALL)
    shares = [t["never_seen_share"] for t in rec["targets"]]
    assert sum(s >= 0.10 for s in shares) >= 4, shares


def test_occluded_determinism_and_record_round_trip(tmp_path: Path, kitchen_occ: Path) -> None:
    make_scene(tmp_path / "again", "kitchen", 0, settings=SMALL)
    assert _digest(tmp_path / "again") == _digest(kitchen_occ)
    a, b = build_scene("kitchen", 0, occluded=True), build_scene("kitchen", 0, occluded=True)
    assert [o.name for o in a.objects] == [o.name for o in b.objects]
    assert all(np.array_equal(x.vertices, y.vertices) for x, y in zip(a.objects, b.objects))
    assert all(o.kind in WRAPPABLE for o in a.targets)


def test_plain_presets_are_unchanged(tmp_path: Path) -> None:
    plain = SceneSettings(width=48, height=40, train_views=6, test_views=3, supersample=1)
    rec = make_scene(tmp_path / "plain", "kitchen", 3, settings=plain)
    assert "occluded" not in rec["settings"] and "never_seen" not in rec["settings"] and "never_seen" not in rec
    assert all(set(t) == {"id", "name", "path"} for t in rec["targets"])
    assert not list((tmp_path / "plain").rglob("never_seen"))
    # the same files as before the occluded variant existed (recorded from commit 39c5420's output)
    json_digest, pixels = _fingerprint(tmp_path / "plain")
    assert json_digest == PLAIN_KITCHEN_JSON
    assert pixels.keys() == PLAIN_KITCHEN_PIXELS.keys()
    for kind, total in PLAIN_KITCHEN_PIXELS.items():
        assert pixels[kind] == pytest.approx(total, rel=2e-3), kind
    for p in PRESETS:  # the plain layouts draw nothing more than before
        plain_scene = build_scene(p, 1)
        assert not any(o.kind in WRAP_KINDS for o in plain_scene.objects)


def test_never_seen_option_on_a_plain_preset_and_errors(tmp_path: Path) -> None:
    rec = make_scene(tmp_path / "ns", "picnic", 0,
                     settings=SceneSettings(width=32, height=32, train_views=8, test_views=2, supersample=1,
                                            never_seen=True))
    assert rec["settings"]["never_seen"] is True and "occluded" not in rec["settings"]
    assert all("never_seen_share" in t for t in rec["targets"])
    with pytest.raises(ConfigError, match="two objects per target"):
        build_scene("kitchen", 0, n_objects=5, n_targets=3, occluded=True)


def test_cli_make_scene_occluded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"
    assert main(["make-scene", str(out), "--preset", "picnic", "--occluded", "--size", "32", "--train-views", "8",
                 "--test-views", "2"]) == 0
    text = capsys.readouterr().out
    assert "never seen in training" in text and "%" in text
    assert (out / "targets").is_dir() and list(out.rglob("never_seen/r_000.png"))
