"""The prune's photo check: flagged Gaussians that the posed photos show stay, those they do not show go.

The scene: a sphere of small Gaussians (the content, one connected piece), three large detached Gaussians that the
photos show (real background, as a capture's sparse far wall) and ten specks that the photos do not show (floaters).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.errors import ConfigError
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.io.blender import write_blender_transforms
from roodi_toolkit.io.files import write_image
from roodi_toolkit.io.ply import read_ply, write_ply
from roodi_toolkit.prune.photo_check import photo_support
from roodi_toolkit.prune.photos import Photos, PhotosUnavailable, find_photos
from roodi_toolkit.prune.scene import prune_cloud
from roodi_toolkit.render.renderer import render_cloud

SIZE = 40
WHITE = (1.0, 1.0, 1.0)


def _scene(seed: int = 0) -> tuple[GaussianCloud, np.ndarray]:
    """Return the cloud and labels: 0 content, 1 real background (in the photos), 2 specks (not in them)."""
    rng = np.random.default_rng(seed)
    n = 1500
    v = rng.normal(size=(n, 3))
    sphere = v / np.linalg.norm(v, axis=1, keepdims=True)
    rgb = np.clip(0.5 + 0.3 * sphere, 0, 1)
    angles = np.array([0.3, 2.4, 4.4])
    wall = np.stack([2.6 * np.cos(angles), 2.6 * np.sin(angles), np.zeros(3)], axis=1)
    angles = rng.uniform(0, 2 * math.pi, 10)
    specks = np.stack([2.0 * np.cos(angles), 2.0 * np.sin(angles), rng.uniform(-0.5, 0.5, 10)], axis=1)
    means = np.concatenate([sphere, wall, specks])
    scales = np.concatenate([np.full((n, 3), 0.05), np.full((3, 3), 0.25), np.full((10, 3), 0.05)])
    colours = np.concatenate([rgb, np.tile([[0.9, 0.1, 0.1]], (3, 1)), rng.uniform(0, 1, (10, 3))])
    cloud = GaussianCloud.from_activated(means, scales=scales, opacities=np.full(len(means), 0.9), rgb=colours)
    return cloud, np.repeat([0, 1, 2], [n, 3, 10])


def _cameras(count: int = 8) -> list[Camera]:
    cams = []
    for i in range(count):
        a = 2 * math.pi * (i + 0.5) / count
        eye = [6.0 * math.cos(a), 6.0 * math.sin(a), 1.5]
        cams.append(Camera(look_at(eye, [0, 0, 0]), intrinsics_from_fov(1.0, SIZE, SIZE), SIZE, SIZE, name=f"v{i}"))
    return cams


def _photos(cloud: GaussianCloud, cameras: list[Camera]) -> Photos:
    import torch

    images = torch.stack([render_cloud(cloud, c, background=WHITE).rgb.clamp(0, 1) for c in cameras]).float()
    return Photos(images, None, cameras, WHITE, "test photos")


@pytest.fixture(scope="module")
def scene():
    cloud, labels = _scene()
    cameras = _cameras()
    return cloud, labels, cameras, _photos(cloud.select(labels != 2), cameras)


def test_without_photos_the_detached_background_goes_with_the_specks(scene):
    cloud, labels, _, _ = scene
    _, keep, report = prune_cloud(cloud)
    assert not keep[labels == 1].any() and not keep[labels == 2].any()
    assert keep[labels == 0].mean() > 0.99
    assert "photo" not in report.mode_reason


def test_the_photos_keep_what_they_show_and_not_the_specks(scene):
    cloud, labels, _, photos = scene
    _, keep, report = prune_cloud(cloud, photos=photos)
    assert keep[labels == 1].all()
    assert not keep[labels == 2].any()
    assert keep[labels == 0].mean() > 0.99
    assert "photo check on test photos" in report.mode_reason
    assert report.statistics["photo_views"] == 8 and report.statistics["photo_supported"] >= 3
    assert report.statistics["photo_psnr"] > report.statistics["photo_psnr_empty"] + 3


def test_support_is_positive_for_shown_negative_for_visible_specks_zero_for_unflagged(scene):
    cloud, labels, _, photos = scene
    flagged = labels > 0
    check = photo_support(cloud, flagged, photos)
    assert (check.support[labels == 1] > 0).all()
    assert (check.support[labels == 2] <= 0).all() and (check.support[labels == 2] < 0).any()
    assert (check.support[labels == 0] == 0).all()
    assert check.views == 8


def test_a_veil_in_front_of_shown_background_is_judged_before_it(scene):
    from roodi_toolkit.progress import null_progress
    from roodi_toolkit.prune.outliers import PruneReport
    from roodi_toolkit.prune.scene import _photo_supported

    cloud, labels, _, photos = scene
    wall = cloud.means[labels == 1].astype(np.float64)  # the three red Gaussians the photos show
    veil = GaussianCloud.from_activated(wall * (3.3 / 2.6), scales=np.full((3, 3), 0.3), opacities=np.full(3, 0.5),
                                        rgb=np.ones((3, 3)), sh_degree=cloud.sh_degree)  # white, between wall and cameras
    both = GaussianCloud.concatenate([cloud, veil])
    front = np.arange(len(both)) >= len(cloud)
    behind = np.concatenate([labels == 1, np.zeros(3, dtype=bool)])
    # judged together, each pixel's change is shared: the veil takes a share of the wall's support and would stay
    together = photo_support(both, front | behind, photos).support
    assert (together[front] > 0).all() and (together[behind] > 0).all()
    # judged first, the veil goes; the wall, judged without it, stays
    supported, figures = _photo_supported(both, front, behind, photos, None, null_progress,
                                          PruneReport(input_count=len(both)))
    assert not supported[front].any() and supported[behind].all()
    assert figures["photo_flagged"] == 6 and figures["photo_supported"] == 3


def test_rgba_photos_count_a_white_fog_that_a_white_background_hides(scene):
    """On RGBA photos the error is taken on black and white: a white Gaussian over white is still wrong."""
    import torch

    cloud, labels, cameras, _ = scene
    clean = cloud.select(labels == 0)
    fog = GaussianCloud.from_activated(np.array([[0.0, 0.0, 1.6]]), scales=np.full((1, 3), 0.3),
                                       opacities=np.array([0.6]), rgb=np.ones((1, 3)))
    both = GaussianCloud.concatenate([clean, fog])
    outs = [render_cloud(clean, c) for c in cameras]
    alphas = torch.stack([o.alpha[..., 0] for o in outs]).float()
    images = torch.stack([o.rgb + (1 - o.alpha) for o in outs]).float()  # on white, as a loader composites
    flagged = np.zeros(len(both), dtype=bool)
    flagged[-1] = True
    rgba = photo_support(both, flagged, Photos(images, alphas, cameras, WHITE, "rgba"))
    white_only = photo_support(both, flagged, Photos(images, None, cameras, WHITE, "white"))
    assert rgba.support[-1] < 0
    assert abs(white_only.support[-1]) < abs(rgba.support[-1])


def test_photos_of_another_frame_are_refused(scene):
    cloud, labels, cameras, _ = scene
    moved = cloud.select(labels != 2)
    moved.means[:] += np.array([20.0, 0.0, 0.0], dtype=np.float32)
    with pytest.raises(ConfigError, match="does not match the photos.*--photos none"):
        photo_support(cloud, labels == 2, _photos(moved, cameras))


def _model_folder(tmp_path, scene):
    """Write the photos as a Blender dataset and the cloud as a trained model folder naming it."""
    cloud, labels, cameras, photos = scene
    data = tmp_path / "data"
    (data / "train").mkdir(parents=True)
    for cam, image in zip(cameras, photos.images):
        write_image(image.numpy(), data / "train" / f"{cam.name}.png")
    write_blender_transforms(data / "transforms_train.json", cameras, [f"train/{c.name}" for c in cameras])
    model = tmp_path / "model"
    ply = model / "point_cloud" / "iteration_10" / "point_cloud.ply"
    ply.parent.mkdir(parents=True)
    write_ply(cloud, ply)
    (model / "cfg.json").write_text(json.dumps({"data_dir": str(data), "downscale": 1, "holdout_every": 0}))
    return model, ply, data


def test_find_photos_reads_the_model_record_and_dataset_folders(tmp_path, scene):
    model, ply, data = _model_folder(tmp_path, scene)
    found = find_photos(ply)
    assert found is not None and len(found.cameras) == 8 and "cfg.json" in found.source
    assert find_photos(ply, "none") is None
    assert find_photos(tmp_path / "elsewhere.ply") is None
    assert len(find_photos(ply, str(model), max_views=3).cameras) == 3
    assert len(find_photos(ply, str(data), downscale=1).cameras) == 8
    with pytest.raises(ConfigError, match="--photos .*missing: no such folder"):
        find_photos(ply, str(tmp_path / "missing"))
    with pytest.raises(ConfigError, match="not a model folder, and not readable as a dataset"):
        find_photos(ply, str(tmp_path / "model" / "point_cloud"))
    (model / "cfg.json").write_text(json.dumps({"data_dir": str(tmp_path / "gone"), "downscale": 1}))
    with pytest.raises(PhotosUnavailable, match="gone that .*cfg.json names is not here"):
        find_photos(ply)
    with pytest.raises(ConfigError, match="--photos .*model: the data folder"):
        find_photos(ply, str(model))


def test_prune_command_goes_on_without_photos_that_are_not_here(tmp_path, scene, run_cli):
    model, ply, data = _model_folder(tmp_path, scene)
    (model / "cfg.json").write_text(json.dumps({"data_dir": str(tmp_path / "gone"), "downscale": 1}))
    result = run_cli("prune", str(ply), str(tmp_path / "out.ply"), "-q")
    assert result.exit_code == 0
    assert "note: no photo check" in result.stderr and "is not here" in result.stderr
    assert "photo check on" not in result.stdout


def test_prune_command_checks_a_model_cloud_against_its_photos(tmp_path, scene, run_cli):
    _, labels, _, _ = scene
    _, ply, _ = _model_folder(tmp_path, scene)
    before = ply.read_bytes()
    result = run_cli("prune", str(ply), str(tmp_path / "out.ply"), "-q")
    assert result.exit_code == 0, result.stderr
    assert "photo check on 8 of the 8 training views" in result.stdout
    kept = read_ply(tmp_path / "out.ply")
    radius = np.linalg.norm(kept.means[:, :2], axis=1)  # content within 1, specks at 2.0, the wall at 2.6
    assert np.isclose(radius, 2.6, atol=1e-4).sum() == 3 and not np.isclose(radius, 2.0, atol=1e-4).any()
    assert len(kept) >= int((labels == 0).sum() * 0.99) + 3
    result = run_cli("prune", str(ply), str(tmp_path / "blind.ply"), "-q", "--photos", "none")
    assert result.exit_code == 0 and "photo" not in result.stdout
    assert len(read_ply(tmp_path / "blind.ply")) < len(kept)
    assert ply.read_bytes() == before


def test_prune_command_writes_nothing_into_the_photos_folders(tmp_path, scene, run_cli):
    """The model folder and the dataset it names are read: they are inputs, whatever the spelling of the path."""
    model, ply, data = _model_folder(tmp_path, scene)
    for out in (model / "clean.ply", data / "train" / ".." / "clean.ply"):
        result = run_cli("prune", str(ply), str(out), "-q")
        assert result.exit_code == 1 and "inside the input folder" in result.stderr
        assert not out.exists()
    result = run_cli("prune", str(ply), str(data / "clean.ply"), "-q", "--photos", "none")
    assert result.exit_code == 0  # without photos the dataset is not read


def test_prune_command_refuses_photos_with_the_statistical_rule(tmp_path, scene, run_cli):
    model, ply, _ = _model_folder(tmp_path, scene)
    result = run_cli("prune", str(ply), str(tmp_path / "out.ply"), "--mode", "statistical", "--photos", str(model))
    assert result.exit_code != 0 and "--photos" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "out.ply").exists()
    result = run_cli("prune", str(ply), str(tmp_path / "out.ply"), "--mode", "statistical", "-q")
    assert result.exit_code == 0 and "photo" not in result.stdout


def test_prune_of_a_lone_ply_does_not_load_torch_or_scipy(tmp_path, scene):
    """Importing PyTorch takes longer than the whole prune of a 150k splat (benchmarks/RESULTS.md, speed): only the
    photo check may load it. Importing SciPy (its sparse graphs, which the pieces were found with before issue 33)
    took 0.22-0.27 CPU s, 12-15% of the command on a 500k real splat: the default prune does without it."""
    import subprocess
    import sys

    cloud, _, _, _ = scene
    write_ply(cloud, tmp_path / "in.ply")
    code = ("import sys; from roodi_toolkit.cli.main import main; "
            f"code = main(['prune', {str(tmp_path / 'in.ply')!r}, {str(tmp_path / 'out.ply')!r}, '-q']); "
            "print(code, 'torch' in sys.modules, 'scipy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split()[-3:] == ["0", "False", "False"], out


def test_inspect_command_shows_the_photo_check_and_writes_nothing_into_its_folders(tmp_path, scene, run_cli):
    """``inspect`` prunes as ``prune`` does: on a model's cloud the photo check runs, and its folders are inputs."""
    model, ply, data = _model_folder(tmp_path, scene)
    result = run_cli("prune", str(ply), str(tmp_path / "out.ply"), "-q")
    assert result.exit_code == 0, result.stderr
    kept = len(read_ply(tmp_path / "out.ply"))
    result = run_cli("inspect", str(ply), "--histogram", str(tmp_path / "h.png"), "-q")
    assert result.exit_code == 0, result.stderr
    assert "photo check on 8 of the 8 training views" in result.stdout and f"{kept:,} would stay\n" in result.stdout
    result = run_cli("inspect", str(ply), "--histogram", str(data / "h.png"), "-q")
    assert result.exit_code == 1 and "inside the input folder" in result.stderr
    assert not (data / "h.png").exists()
