"""Moving, turning and scaling clouds (roodi_toolkit.similarity): exact SH rotation of every band, renders unchanged
when cloud and cameras move together, and `convert -t/-r/-s` checked against splat-transform 2.7.1's own output on a
generated SH-3 cloud and on a real SH-2 splat."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.similarity import (Similarity, _sh_basis_values, euler_rotation, rotation_between, sh_rotation,
                                      splat_transform_actions, transform_cloud)
from roodi_toolkit.sh import eval_sh_colors, sh_bases
from tests.io.test_formats import _splat_transform, make_cloud

REAL_SH = Path(__file__).parent / "data" / "real_sh" / "playbot_lod3_1000.ply"


def _random_rotation(seed: int) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=4)
    from roodi_toolkit.gaussians import quat_to_rotmat

    return quat_to_rotmat(q[None])[0]


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_rotated_sh_gives_the_old_colour_from_the_turned_direction(degree: int) -> None:
    rng = np.random.default_rng(degree)
    k = (degree + 1) ** 2
    sh = torch.from_numpy(rng.normal(size=(200, k, 3)))
    R = _random_rotation(degree)
    turned = sh.clone()
    turned[:, 1:] = torch.einsum("ij,njc->nic", torch.from_numpy(sh_rotation(R, degree)), sh[:, 1:])
    dirs = torch.from_numpy(rng.normal(size=(200, 3)))
    before = eval_sh_colors(sh + 5.0 * (torch.arange(k) == 0)[None, :, None], dirs)  # +5 DC: nothing clamps at 0
    after = eval_sh_colors(turned + 5.0 * (torch.arange(k) == 0)[None, :, None], dirs @ torch.from_numpy(R).T)
    torch.testing.assert_close(after, before, atol=1e-12, rtol=0)


def test_numpy_sh_basis_is_the_renderers() -> None:
    dirs = np.random.default_rng(0).normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    np.testing.assert_array_equal(_sh_basis_values(3, dirs), sh_bases(3, torch.from_numpy(dirs)).numpy())


def test_sh_rotations_compose_and_are_orthogonal() -> None:
    A, B = _random_rotation(1), _random_rotation(2)
    M = sh_rotation(A @ B, 3)
    np.testing.assert_allclose(M, sh_rotation(A, 3) @ sh_rotation(B, 3), atol=1e-12)
    np.testing.assert_allclose(M @ M.T, np.eye(15), atol=1e-12)


def test_similarity_algebra_and_refusals() -> None:
    a = Similarity(euler_rotation(10, 20, 30), np.array([1.0, -2.0, 0.5]), 1.7)
    b = Similarity(euler_rotation(-40, 5, 0), np.array([0.0, 3.0, 1.0]), 0.3)
    p = np.random.default_rng(0).normal(size=(10, 3))
    np.testing.assert_allclose(a.then(b).apply(p), b.apply(a.apply(p)), atol=1e-12)
    np.testing.assert_allclose(a.inverse().apply(a.apply(p)), p, atol=1e-12)
    back = Similarity.from_matrix(a.matrix()[:3])
    np.testing.assert_allclose(back.matrix(), a.matrix(), atol=1e-12)
    with pytest.raises(ConfigError, match="mirrors"):
        Similarity.from_matrix(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ConfigError, match="not a rotation"):
        Similarity.from_matrix(np.diag([1.0, 2.0, 1.0, 1.0]))
    with pytest.raises(ConfigError, match="scale"):
        Similarity(scale=0.0)
    np.testing.assert_allclose(rotation_between([0, 0, -1], [0, 0, 1]) @ [0, 0, -1], [0, 0, 1], atol=1e-12)


def test_moved_cloud_renders_the_same_from_moved_cameras() -> None:
    from roodi_toolkit.cameras import Camera, look_at, intrinsics_from_fov
    from roodi_toolkit.render.renderer import render_cloud

    cloud = make_cloud(300, degree=3)
    cloud.means *= 0.4
    cloud.opacity_logits[:] = 1.0
    move = Similarity(euler_rotation(25, -60, 140), np.array([3.0, -1.0, 2.0]), 2.5)
    moved = transform_cloud(cloud, move)
    for eye in ([0.0, -4.0, 1.0], [3.0, 2.0, -2.0]):
        w2c = look_at(eye, [0.0, 0.0, 0.0])
        K = intrinsics_from_fov(0.9, 40, 32)
        cam = Camera(w2c, K, 40, 32)
        # the same camera in the moved world: its centre moves with the points, its axes turn with them
        c2w = np.linalg.inv(w2c)
        c2w_new = np.eye(4)
        c2w_new[:3, :3] = move.rotation @ c2w[:3, :3]
        c2w_new[:3, 3] = move.apply(c2w[:3, 3][None])[0]
        cam_new = Camera(np.linalg.inv(c2w_new), K, 40, 32, near=cam.near * move.scale)
        a = render_cloud(cloud, cam, sh_degree=3).rgb
        b = render_cloud(moved, cam_new, sh_degree=3).rgb
        assert float(a.std()) > 0.05  # something is drawn
        torch.testing.assert_close(b, a, atol=2e-4, rtol=0)


def _compare(ours, theirs) -> dict:
    d = {"means": float(np.abs(ours.means - theirs.means).max() / max(np.abs(theirs.means).max(), 1e-9)),
         "log_scales": float(np.abs(ours.log_scales - theirs.log_scales).max()),
         "rotation": float(np.abs(np.abs((ours.quats_normalized * theirs.quats_normalized).sum(1)) - 1).max()),
         "sh_rest": float(np.abs(ours.sh_rest - theirs.sh_rest).max()) if ours.sh_degree else 0.0,
         "other": float(max(np.abs(ours.sh_dc - theirs.sh_dc).max(),
                            np.abs(ours.opacity_logits - theirs.opacity_logits).max()))}
    return d


ACTIONS = [
    ["-r", "0,0,90"],
    ["-r", "30,-45,120", "-t", "1,2,-3"],
    ["-s", "2", "-t", "0.5,0,1", "-r", "90,0,0", "-s", "0.25", "-r", "-10,80,5"],
]


@pytest.mark.parametrize("actions", ACTIONS, ids=["quarter-turn", "turn-move", "mixed"])
def test_convert_moves_like_splat_transform_sh3(tmp_path: Path, run_cli, actions: list[str]) -> None:
    tool = _splat_transform()
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.io.splat import write_cloud

    src = write_cloud(make_cloud(400, degree=3), tmp_path / "src.ply")
    theirs = tmp_path / "theirs.ply"
    run = subprocess.run([tool, "-q", "-w", "-g", "cpu", str(src), *actions, str(theirs)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    res = run_cli("convert", src, tmp_path / "ours.ply", *actions)
    assert res.exit_code == 0, res.stderr
    d = _compare(read_ply(tmp_path / "ours.ply"), read_ply(theirs))
    assert d["means"] < 1e-6 and d["log_scales"] < 1e-6 and d["rotation"] < 1e-6 and d["other"] == 0, d
    assert d["sh_rest"] < 1e-5, d  # float32 rounding of band 3 sums of up to 7 terms


def test_convert_moves_a_real_sh_splat_like_splat_transform(tmp_path: Path, run_cli) -> None:
    tool = _splat_transform()
    from roodi_toolkit.io.ply import read_ply

    actions = ["-r", "17,-33,71", "-t", "0.2,-0.1,0.3", "-s", "1.5"]
    theirs = tmp_path / "theirs.ply"
    run = subprocess.run([tool, "-q", "-w", "-g", "cpu", str(REAL_SH), *actions, str(theirs)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    res = run_cli("convert", REAL_SH, tmp_path / "ours.ply", *actions)
    assert res.exit_code == 0, res.stderr
    original, ours, st = read_ply(REAL_SH), read_ply(tmp_path / "ours.ply"), read_ply(theirs)
    assert original.sh_degree == 2 and np.abs(original.sh_rest).max() > 1.0  # real view-dependent colour
    assert np.abs(ours.sh_rest - original.sh_rest).max() > 0.1  # it did turn
    d = _compare(ours, st)
    assert d["means"] < 1e-6 and d["log_scales"] < 1e-6 and d["rotation"] < 1e-6 and d["sh_rest"] < 1e-5, d


def test_convert_up_turns_that_direction_to_z(tmp_path: Path, run_cli) -> None:
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.io.splat import write_cloud

    c = make_cloud(50, degree=1)
    c.means[:] = np.array([0.0, -1.0, 0.0]) * np.arange(50)[:, None]  # a line down the file's -y
    src = write_cloud(c, tmp_path / "src.ply")
    res = run_cli("convert", src, tmp_path / "up.ply", "--up", "0,-1,0")
    assert res.exit_code == 0, res.stderr
    out = read_ply(tmp_path / "up.ply")
    np.testing.assert_allclose(out.means, np.arange(50)[:, None] * np.array([0.0, 0.0, 1.0]), atol=1e-5)


@pytest.mark.parametrize("args, needle", [
    (["-s", "0"], "--scale"), (["-t", "1,2"], "--translate"), (["-r", "a,b,c"], "--rotate"),
    (["--up", "0,0,0"], "--up"), (["-s", "nan"], "--scale"),
])
def test_convert_refuses_bad_moves_naming_the_option(tmp_path: Path, run_cli, args: list[str], needle: str) -> None:
    from roodi_toolkit.io.splat import write_cloud

    src = write_cloud(make_cloud(20), tmp_path / "src.ply")
    res = run_cli("convert", src, tmp_path / "o.ply", *args)
    assert res.exit_code in (1, 2), res.stderr
    assert needle in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert not (tmp_path / "o.ply").exists()


def test_splat_transform_actions_compose_in_command_line_order() -> None:
    a = splat_transform_actions([("translate", (1.0, 0.0, 0.0)), ("rotate", (0.0, 0.0, 90.0))])
    b = splat_transform_actions([("rotate", (0.0, 0.0, 90.0)), ("translate", (1.0, 0.0, 0.0))])
    p = np.zeros((1, 3))
    # engine frame: translate then turn puts the origin at (0, 1, 0); the file holds engine (-x, -y, z)
    np.testing.assert_allclose(a.apply(p), [[0.0, -1.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(b.apply(p), [[-1.0, 0.0, 0.0]], atol=1e-12)
