import math

import numpy as np
import pytest

from roodi_toolkit.cameras import (Camera, intrinsics_from_fov, invert_rigid, look_at, opengl_c2w_to_w2c,
                                   orbit_cameras, w2c_to_opengl_c2w)
from roodi_toolkit.errors import ConfigError


def test_look_at_is_a_rigid_opencv_pose():
    w2c = look_at([1.0, -3.0, 2.0], [0.2, 0.1, 0.3])
    R = w2c[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # the target lies on the optical axis in front of the camera; world up (+z) points up in the image (-y)
    target_cam = R @ np.array([0.2, 0.1, 0.3]) + w2c[:3, 3]
    assert target_cam[0] == pytest.approx(0, abs=1e-12) and target_cam[1] == pytest.approx(0, abs=1e-12)
    assert target_cam[2] > 0
    assert (R @ np.array([0.0, 0.0, 1.0]))[1] < 0


def test_look_at_straight_down_does_not_degenerate():
    w2c = look_at([0, 0, 5], [0, 0, 0])
    assert np.isfinite(w2c).all()
    np.testing.assert_allclose((w2c[:3, :3] @ np.zeros(3) + w2c[:3, 3]), [0, 0, 5], atol=1e-12)


def test_opengl_conversion_roundtrip_and_axes():
    w2c = look_at([2.0, 1.0, 1.5], [0, 0, 0])
    c2w_gl = w2c_to_opengl_c2w(w2c)
    np.testing.assert_allclose(opengl_c2w_to_w2c(c2w_gl), w2c, atol=1e-12)
    # OpenGL cameras look down their -z axis
    forward_world = -c2w_gl[:3, 2]
    expected = -np.array([2.0, 1.0, 1.5]) / np.linalg.norm([2.0, 1.0, 1.5])
    np.testing.assert_allclose(forward_world, expected, atol=1e-12)
    np.testing.assert_allclose(opengl_c2w_to_w2c(c2w_gl[:3]), w2c, atol=1e-12)


def test_projection_and_intrinsics():
    K = intrinsics_from_fov(math.radians(90), 100, 80)
    assert K[0, 0] == pytest.approx(50.0) and K[0, 2] == 50 and K[1, 2] == 40
    cam = Camera(look_at([0, -2, 0], [0, 0, 0]), K, 100, 80)
    uv, z = cam.project(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [50, 40])
    np.testing.assert_allclose(uv[1], [75, 40])  # +x world is image right
    np.testing.assert_allclose(uv[2], [50, 15])  # +z world (up) is image up
    np.testing.assert_allclose(z, [2, 2, 2])
    np.testing.assert_allclose(cam.center, [0, -2, 0], atol=1e-12)
    np.testing.assert_allclose(invert_rigid(cam.camera_to_world), cam.world_to_camera, atol=1e-12)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (50, 40) and half.K[0, 0] == pytest.approx(25)


def test_orbit_cameras_look_at_centre_from_radius():
    cams = orbit_cameras([1.0, 2.0, 0.5], 3.0, 8, elevation_deg=30, width=64, height=48)
    assert len(cams) == 8 and len({c.name for c in cams}) == 8
    for cam in cams:
        assert np.linalg.norm(cam.center - [1.0, 2.0, 0.5]) == pytest.approx(3.0)
        assert cam.center[2] - 0.5 == pytest.approx(3.0 * math.sin(math.radians(30)))
        uv, z = cam.project(np.array([[1.0, 2.0, 0.5]]))
        np.testing.assert_allclose(uv[0], [32, 24], atol=1e-9)


def test_camera_validation():
    with pytest.raises(ConfigError, match="world_to_camera must be"):
        Camera(np.eye(3), np.eye(3), 10, 10)
    with pytest.raises(ConfigError, match="near < far"):
        Camera(np.eye(4), np.eye(3), 10, 10, near=2, far=1)
    with pytest.raises(ConfigError, match="NaN"):
        Camera(np.full((4, 4), np.nan), np.eye(3), 10, 10)


def test_spread_cameras_cover_the_scene_whatever_its_scale_and_order():
    from roodi_toolkit.cameras import orbit_cameras, spread_cameras

    ring = orbit_cameras((0, 0, 0), 3.0, 12)
    assert spread_cameras(ring, 4) == [0, 3, 6, 9]
    far = orbit_cameras((5, 5, 5), 300.0, 12)  # the same ring, elsewhere and 100 times larger
    assert spread_cameras(far, 4) == [0, 3, 6, 9]
    # a capture walked twice round: the second pass adds nothing a spread choice needs
    twice = ring + orbit_cameras((0, 0, 0), 3.0, 12)
    assert len(set(i % 12 for i in spread_cameras(twice, 6))) == 6
    # cameras at one pose are still chosen once each; all of them when k is not below their number
    same = [ring[0]] * 5
    assert spread_cameras(same, 3) == [0, 1, 2] and spread_cameras(ring, 12) == list(range(12))
