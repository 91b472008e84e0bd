"""``roodi-toolkit render`` and the library behind it: orbit framing, dataset cameras, depth encoding."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.io.files import read_image
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.io.ply import write_ply
from roodi_toolkit.render.views import DepthEncoding, depth_encoding_for, framing_orbit, render_views


def ball_cloud(n=300, seed=0, center=(1.0, 2.0, 0.5)):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return GaussianCloud.from_activated(np.asarray(center) + 0.5 * d, scales=np.full((n, 3), 0.06),
                                        opacities=np.full(n, 0.95), rgb=np.tile([0.9, 0.3, 0.1], (n, 1)))


def test_framing_orbit_puts_the_cloud_in_view():
    cloud = ball_cloud()
    cams = framing_orbit(cloud, 4, width=64, height=48)
    assert len(cams) == 4
    for cam in cams:
        uv, z = cam.project(cloud.means)
        assert (z > 0).all()
        assert (uv[:, 0] > 0).all() and (uv[:, 0] < 64).all() and (uv[:, 1] > 0).all() and (uv[:, 1] < 48).all()
        center = np.median(cloud.means, axis=0)[None]  # the orbit looks at the per-axis median
        np.testing.assert_allclose(cam.project(center)[0][0], [32, 24], atol=1e-6)


def test_depth_encoding_round_trip_and_range():
    cloud = ball_cloud()
    cams = framing_orbit(cloud, 2, width=32, height=32)
    enc = depth_encoding_for(cloud, cams)
    far = max(cam.project(cloud.means)[1].max() for cam in cams)
    assert enc.scale == pytest.approx(far / 65535)
    depth = np.array([[far, far / 2], [1.0, 5.0]])
    png = enc.encode(depth, np.array([[1.0, 0.9], [0.1, 1.0]]))
    assert png.dtype == np.uint16 and png[1, 0] == 0 and png[0, 0] == 65535
    np.testing.assert_allclose(enc.decode(png)[0], depth[0], atol=enc.scale)
    assert np.isnan(DepthEncoding(1.0).decode(np.zeros((1, 1), np.uint16))).all()


def test_render_views_depth_matches_geometry(tmp_path):
    cloud = ball_cloud(n=2000, center=(0.0, 0.0, 0.0))
    cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(math.radians(40), 33, 33), 33, 33,
                 name="front")
    record = render_views(cloud, [cam], tmp_path, what="depth")
    png = read_image(tmp_path / "front_depth.png")
    assert png.dtype == np.uint16 and png.shape == (33, 33)
    depth = png.astype(float) * record["depth"]["scale"]
    assert depth[16, 16] == pytest.approx(2.5, abs=0.08)  # the near surface of a 0.5-radius sphere at distance 3
    assert png[0, 0] == 0  # the corner sees no surface
    assert read_image(tmp_path / "front_depth_preview.png").shape == (33, 33, 3)
    saved = json.loads((tmp_path / "render.json").read_text())
    assert saved["views"][0]["files"] == ["front_depth.png", "front_depth_preview.png"]


def test_cli_render_orbit_rgb_and_alpha(tmp_path, run_cli):
    ply = tmp_path / "ball.ply"
    write_ply(ball_cloud(), ply)
    out = tmp_path / "renders"
    res = run_cli("render", ply, out, "--orbit", "3", "--size", "40x30", "--background", "0,0,1", "-q")
    assert res.exit_code == 0, res.stderr
    imgs = sorted(p.name for p in out.glob("*.png"))
    assert imgs == ["orbit_000.png", "orbit_001.png", "orbit_002.png"]
    img = read_image(out / "orbit_000.png")
    assert img.shape == (30, 40, 3)
    assert tuple(img[0, 0]) == (0, 0, 255)  # background in the corner
    assert img[15, 20, 0] > 200 and img[15, 20, 2] < 60  # the orange ball in the middle
    # refuses to write into a non-empty folder without --overwrite
    res = run_cli("render", ply, out, "--orbit", "1", "--size", "8x8", "-q")
    assert res.exit_code == 1 and "--overwrite" in res.stderr
    res = run_cli("render", ply, out, "--orbit", "1", "--size", "8x8", "--what", "alpha", "--overwrite", "-q")
    assert res.exit_code == 0 and read_image(out / "orbit_000_alpha.png").shape == (8, 8)


def test_cli_render_blender_cameras(tmp_path, run_cli):
    from roodi_toolkit.cameras import orbit_cameras
    from roodi_toolkit.io.blender import write_blender_transforms

    cloud = ball_cloud(center=(0.0, 0.0, 0.0))
    ply = tmp_path / "ball.ply"
    write_ply(cloud, ply)
    cams = orbit_cameras([0, 0, 0], 3.0, 2, width=24, height=20)
    data = tmp_path / "data"  # the dataset folder is an input: outputs go beside it, never inside
    data.mkdir()
    # the file states w/h: its images need not exist to render its cameras
    transforms = write_blender_transforms(data / "transforms_test.json", cams, ["./test/r_0", "./test/r_1"])
    assert not (data / "test").exists()
    out = tmp_path / "views"
    res = run_cli("render", ply, out, "--cameras", transforms, "--size", "48x40", "--what", "depth", "-q")
    assert res.exit_code == 0, res.stderr
    assert sorted(p.name for p in out.glob("*_depth.png")) == ["r_0_depth.png", "r_1_depth.png"]
    assert read_image(out / "r_0_depth.png").shape == (40, 48)
    res = run_cli("render", ply, tmp_path / "v2", "--cameras", transforms, "-q")
    assert res.exit_code == 0 and read_image(tmp_path / "v2" / "r_1.png").shape == (20, 24, 3)
    # without w/h the image sizes are needed, and a missing image is named
    meta = json.loads(transforms.read_text())
    del meta["w"], meta["h"], meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]
    transforms.write_text(json.dumps(meta))
    res = run_cli("render", ply, tmp_path / "v3", "--cameras", transforms, "-q")
    assert res.exit_code == 1 and "frame 0 image not found" in res.stderr and not (tmp_path / "v3").exists()


def _up_cameras(up, n=6):
    from roodi_toolkit.cameras import orbit_cameras

    return orbit_cameras([0, 0, 0], 3.0, n, elevation_deg=15.0, width=24, height=20, up=up)


@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (0.6, 0.0, 0.8)])
def test_cameras_up_is_the_capture_up(up):
    from roodi_toolkit.render.views import cameras_up

    np.testing.assert_allclose(cameras_up(_up_cameras(up)), up, atol=1e-9)


def test_cli_render_up_from_cameras_and_frame_like(tmp_path, run_cli):
    from roodi_toolkit.io.blender import write_blender_transforms

    ply, other = tmp_path / "ball.ply", tmp_path / "small.ply"
    write_ply(ball_cloud(), ply)
    write_ply(ball_cloud(n=50, seed=3, center=(3.0, 0.0, 0.0)), other)
    data = tmp_path / "data"
    data.mkdir()
    write_blender_transforms(data / "transforms_train.json", _up_cameras((0.0, -1.0, 0.0)), ["a"] * 6)

    res = run_cli("render", ply, tmp_path / "a", "--orbit", "2", "--size", "16x16", "--up", data)
    assert res.exit_code == 0, res.stderr
    rec = json.loads((tmp_path / "a" / "render.json").read_text())
    np.testing.assert_allclose(rec["orbit"]["up"], [0, -1, 0], atol=1e-9)
    assert "mean up of the cameras" in rec["orbit"]["up_from"]
    # the default stays z up for a bare cloud
    assert run_cli("render", ply, tmp_path / "b", "--orbit", "2", "--size", "16x16", "-q").exit_code == 0
    np.testing.assert_allclose(json.loads((tmp_path / "b" / "render.json").read_text())["orbit"]["up"], [0, 0, 1])
    # --frame-like: the very views another cloud's own render has
    assert run_cli("render", other, tmp_path / "c", "--orbit", "3", "--size", "16x16", "-q").exit_code == 0
    res = run_cli("render", ply, tmp_path / "d", "--orbit", "3", "--size", "16x16", "--frame-like", other, "-q")
    assert res.exit_code == 0, res.stderr
    own = json.loads((tmp_path / "c" / "render.json").read_text())["views"]
    like = json.loads((tmp_path / "d" / "render.json").read_text())["views"]
    for a, b in zip(own, like):
        np.testing.assert_allclose(a["world_to_camera"], b["world_to_camera"])
        np.testing.assert_allclose(a["K"], b["K"])
    res = run_cli("render", ply, tmp_path / "e", "--orbit", "2", "--up", "0,0,0", "-q")
    assert res.exit_code == 1 and "--up" in res.stderr and not (tmp_path / "e").exists()
    res = run_cli("render", ply, tmp_path / "f", "--cameras", data, "--frame-like", other, "-q")
    assert res.exit_code == 2
    # --up auto works on a bare cloud: a ball has no ground plane, so z up by default, and it says so
    res = run_cli("render", ply, tmp_path / "g", "--orbit", "2", "--size", "16x16", "--up", "auto")
    assert res.exit_code == 0, res.stderr
    assert "orbit up 0, 0, 1: z up by default: no cameras, no convention" in res.stderr


def test_render_up_defaults_to_the_models_training_cameras(tmp_path, run_cli):
    from roodi_toolkit.io.blender import write_blender_transforms
    from roodi_toolkit.io.files import write_json

    data, model = tmp_path / "data", tmp_path / "model"
    data.mkdir()
    write_blender_transforms(data / "transforms_train.json", _up_cameras((0.0, -1.0, 0.0)), ["a"] * 6)
    ply = model / "point_cloud" / "iteration_5" / "point_cloud.ply"
    ply.parent.mkdir(parents=True)
    write_ply(ball_cloud(), ply)
    write_json({"data_dir": str(data), "iterations": 5}, model / "cfg.json")
    for args in ((), ("--up", "auto")):
        out = tmp_path / f"r{len(args)}"
        assert run_cli("render", ply, out, "--orbit", "2", "--size", "16x16", *args, "-q").exit_code == 0
        rec = json.loads((out / "render.json").read_text())["orbit"]
        np.testing.assert_allclose(rec["up"], [0, -1, 0], atol=1e-9)
        assert rec["up_from"] == "the mean up of the model's training cameras"


def test_cli_render_errors(tmp_path, run_cli):
    ply = tmp_path / "ball.ply"
    write_ply(ball_cloud(), ply)
    res = run_cli("render", ply, tmp_path / "o", "--renderer", "nope")
    assert res.exit_code == 1 and "no renderer plugin named 'nope'" in res.stderr
    res = run_cli("render", ply, tmp_path / "o", "--cameras", tmp_path, "--orbit", "2")
    assert res.exit_code == 2
    res = run_cli("render", tmp_path / "missing.ply", tmp_path / "o")
    assert res.exit_code == 1 and "missing.ply" in res.stderr
    res = run_cli("render", ply, tmp_path / "o", "--background", "2,0,0")
    assert res.exit_code == 2
