"""Tests of the posed-image loaders and the COLMAP reader/writer, on fixtures written here."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from roodi_toolkit.cameras import Camera, look_at, orbit_cameras, qvec_to_rotmat, rotmat_to_qvec
from roodi_toolkit.io.blender import load_blender, write_blender_transforms
from roodi_toolkit.io.colmap import (
    ColmapCamera,
    ColmapPoints,
    UnsupportedCameraModelError,
    colmap_model_from_cameras,
    load_colmap,
    read_colmap_model,
    write_colmap_model,
)
from roodi_toolkit.io.dataset import Dataset, detect_format, estimate_bounds, load_cameras, load_dataset
from roodi_toolkit.errors import DatasetError, RoodiError
from roodi_toolkit.io.files import write_image

W, H = 16, 12


def _cams(n: int, width: int = W, height: int = H) -> list[Camera]:
    cams = orbit_cameras([0.1, -0.2, 0.3], 3.0, n, elevation_deg=25.0, width=width, height=height, fov_x_deg=60.0)
    return [Camera(c.world_to_camera, c.K, c.width, c.height, name=f"r_{i}") for i, c in enumerate(cams)]


def _rgba(seed: int, width: int = W, height: int = H) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, size=(height, width, 4), dtype=np.uint8)
    img[0, 0, 3] = 0  # one fully transparent pixel
    img[0, 1, 3] = 255
    return img


def _blender_fixture(root: Path, n_train: int = 3, n_test: int = 2, *, masks: bool = False,
                     drop_ext: bool = True) -> dict[str, list]:
    (root / "train").mkdir(parents=True)
    (root / "test").mkdir()
    out: dict[str, list] = {}
    for split, n, off in (("train", n_train, 0), ("test", n_test, 100)):
        cams = _cams(n)
        imgs = [_rgba(off + i) for i in range(n)]
        extra = []
        for i, (c, img) in enumerate(zip(cams, imgs)):
            write_image(img, root / split / f"{c.name}.png")
            if masks:
                write_image(np.full((H, W), i + 1, np.uint8), root / split / f"{c.name}_mask.png")
                extra.append({"mask_path": f"{split}/{c.name}_mask.png"})
        paths = [f"./{split}/{c.name}" + ("" if drop_ext else ".png") for c in cams]
        write_blender_transforms(root / f"transforms_{split}.json", cams, paths, frame_extra=extra or None)
        out[split] = [cams, imgs]
    return out


# ------------------------------------------------------------------------------------------------------ Blender


def test_blender_round_trip_cameras_images_and_splits(tmp_path: Path) -> None:
    fx = _blender_fixture(tmp_path)
    ds = load_dataset(tmp_path)
    assert isinstance(ds, Dataset) and ds.format == "blender"
    assert ds.splits == ["train"] * 3 + ["test"] * 2
    assert ds.images.shape == (5, H, W, 3) and ds.images.dtype == torch.float32
    assert ds.alphas is not None and ds.alphas.shape == (5, H, W)
    cams = fx["train"][0] + fx["test"][0]
    imgs = fx["train"][1] + fx["test"][1]
    for c_loaded, c_ref in zip(ds.cameras, cams):
        np.testing.assert_allclose(c_loaded.world_to_camera, c_ref.world_to_camera, atol=1e-9)
        np.testing.assert_allclose(c_loaded.K, c_ref.K, atol=1e-9)
        assert c_loaded.name == c_ref.name
    # RGBA composited on the default white background
    ref = imgs[0].astype(np.float32) / 255.0
    expected = ref[..., :3] * ref[..., 3:] + (1.0 - ref[..., 3:])
    np.testing.assert_allclose(ds.images[0].numpy(), expected, atol=1e-6)
    np.testing.assert_allclose(ds.images[0, 0, 0].numpy(), [1.0, 1.0, 1.0])
    assert ds.train_indices == [0, 1, 2] and ds.test_indices == [3, 4]
    assert len(ds.split("test")) == 2 and ds.split("test").cameras[0].name == cams[3].name


def test_blender_background_downscale_and_masks(tmp_path: Path) -> None:
    _blender_fixture(tmp_path, masks=True, drop_ext=False)
    black = load_blender(tmp_path, background=(0, 0, 0), splits=["train"])
    assert len(black) == 3 and black.background == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(black.images[0, 0, 0].numpy(), [0.0, 0.0, 0.0])
    assert black.masks is not None and black.masks.dtype == torch.int64
    assert black.masks[1].unique().tolist() == [2]
    half = load_blender(tmp_path, downscale=2, splits=["train"])
    assert half.images.shape == (3, H // 2, W // 2, 3) and half.masks.shape == (3, H // 2, W // 2)
    full = load_blender(tmp_path, splits=["train"])
    np.testing.assert_allclose(half.cameras[0].K[:2], full.cameras[0].K[:2] / 2)
    # area averaging: each output pixel is the mean of a 2x2 block
    np.testing.assert_allclose(half.images[0, 1, 2].numpy(), full.images[0, 2:4, 4:6].mean(dim=(0, 1)).numpy(),
                               atol=1e-6)


def test_blender_original_nerf_synthetic_keys_only(tmp_path: Path) -> None:
    # the original files carry camera_angle_x and frames only; images stored without extension in file_path
    (tmp_path / "train").mkdir()
    c2w = np.array([[1, 0, 0, 0], [0, 0, -1, -4], [0, 1, 0, 0.5], [0, 0, 0, 1]], float)  # looks along +y
    write_image(np.zeros((8, 10, 3), np.uint8), tmp_path / "train" / "r_0.png")
    (tmp_path / "transforms_train.json").write_text(json.dumps(
        {"camera_angle_x": 0.8, "frames": [{"file_path": "./train/r_0", "rotation": 0.1,
                                            "transform_matrix": c2w.tolist()}]}))
    cams = load_cameras(tmp_path)
    assert (cams[0].width, cams[0].height) == (10, 8)
    np.testing.assert_allclose(cams[0].K[0, 0], 5.0 / math.tan(0.4))
    uv, z = cams[0].project(np.array([[0.0, 0.0, 0.5]]))  # a point straight ahead projects on the centre
    np.testing.assert_allclose(uv[0], [5.0, 4.0], atol=1e-9)
    np.testing.assert_allclose(z, [4.0])
    ds = load_dataset(tmp_path / "transforms_train.json")
    assert ds.alphas is None and ds.images.shape == (1, 8, 10, 3)


@pytest.mark.parametrize("case, needle", [
    ("malformed", "malformed"),
    ("no_frames", "frames"),
    ("no_angle", "camera_angle_x"),
    ("missing_image", "not found"),
    ("sizes", "at most 10%"),
    ("bad_matrix", "transform_matrix"),
])
def test_blender_errors_name_file_and_problem(tmp_path: Path, case: str, needle: str) -> None:
    _blender_fixture(tmp_path, n_train=2, n_test=1)
    tf = tmp_path / "transforms_train.json"
    meta = json.loads(tf.read_text())
    if case == "malformed":
        tf.write_text(tf.read_text()[:-10])
    elif case == "no_frames":
        del meta["frames"]
        tf.write_text(json.dumps(meta))
    elif case == "no_angle":
        for k in ("camera_angle_x", "fl_x"):
            del meta[k]
        tf.write_text(json.dumps(meta))
    elif case == "missing_image":
        (tmp_path / "train" / "r_1.png").unlink()
    elif case == "sizes":
        write_image(np.zeros((H + 2, W, 3), np.uint8), tmp_path / "train" / "r_1.png")
    elif case == "bad_matrix":
        meta["frames"][0]["transform_matrix"] = [[1, 0], [0, 1]]
        tf.write_text(json.dumps(meta))
    with pytest.raises(DatasetError) as exc:
        load_dataset(tmp_path)
    msg = str(exc.value)
    assert needle in msg
    assert "transforms_train.json" in msg or "r_1" in msg


def test_detect_format_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="not found"):
        detect_format(tmp_path / "nope")
    with pytest.raises(DatasetError, match="no dataset found"):
        load_dataset(tmp_path)
    with pytest.raises(DatasetError, match="downscale"):
        _blender_fixture(tmp_path / "d")
        load_dataset(tmp_path / "d", downscale=0.5)


# ------------------------------------------------------------------------------------------------------- COLMAP


def test_quaternion_round_trip() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[0] >= 0 else -q
        R = qvec_to_rotmat(q)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(rotmat_to_qvec(R), q, atol=1e-9)
    # a 180-degree rotation (w = 0) is where naive trace-based conversions fail
    np.testing.assert_allclose(np.abs(rotmat_to_qvec(np.diag([1.0, -1.0, -1.0]))), [0, 1, 0, 0], atol=1e-12)


def _colmap_fixture(root: Path, n: int = 10, *, binary: bool, model: str = "PINHOLE") -> tuple[list[Camera], object]:
    cams = _cams(n)
    rng = np.random.default_rng(1)
    pts = ColmapPoints(np.arange(1, 41), rng.normal(size=(40, 3)), rng.integers(0, 256, (40, 3)),
                       rng.uniform(0, 1, 40), [rng.integers(1, n + 1, size=(k % 4, 2)) for k in range(40)])
    names = [f"img_{i:02d}.png" for i in range(n)]
    m = colmap_model_from_cameras(cams, names, pts, model=model)
    first = next(iter(m.images.values()))
    first.xys = rng.uniform(0, W, size=(3, 2))
    first.point3d_ids = np.array([1, -1, 7])
    sparse = root / "sparse" / "0"
    sparse.mkdir(parents=True)
    write_colmap_model(m, sparse, binary=binary)
    (root / "images").mkdir()
    for i, name in enumerate(names):
        write_image(_rgba(i)[..., :3], root / "images" / name)
    return cams, m


@pytest.mark.parametrize("binary", [True, False])
def test_colmap_write_read_round_trip(tmp_path: Path, binary: bool) -> None:
    cams, model = _colmap_fixture(tmp_path, binary=binary)
    ext = ".bin" if binary else ".txt"
    assert (tmp_path / "sparse" / "0" / f"images{ext}").is_file()
    back = read_colmap_model(tmp_path / "sparse" / "0")
    assert back.cameras.keys() == model.cameras.keys()
    for k, cam in model.cameras.items():
        assert back.cameras[k].model == cam.model and back.cameras[k].width == cam.width
        np.testing.assert_array_equal(back.cameras[k].params, cam.params)
    for k, img in model.images.items():
        b = back.images[k]
        assert b.name == img.name and b.camera_id == img.camera_id
        np.testing.assert_array_equal(b.qvec_wxyz, img.qvec_wxyz)
        np.testing.assert_array_equal(b.tvec, img.tvec)
        np.testing.assert_array_equal(b.xys, img.xys)
        np.testing.assert_array_equal(b.point3d_ids, img.point3d_ids)
    np.testing.assert_array_equal(back.points.xyz, model.points.xyz)
    np.testing.assert_array_equal(back.points.rgb, model.points.rgb)
    for a, b in zip(back.points.tracks, model.points.tracks):
        np.testing.assert_array_equal(a, b)


def test_colmap_binary_and_text_load_the_same_dataset(tmp_path: Path) -> None:
    cams, _ = _colmap_fixture(tmp_path / "b", binary=True)
    _colmap_fixture(tmp_path / "t", binary=False)
    db, dt = load_dataset(tmp_path / "b"), load_dataset(tmp_path / "t")
    assert db.format == dt.format == "colmap"
    torch.testing.assert_close(db.images, dt.images)
    for a, b, ref in zip(db.cameras, dt.cameras, cams):
        np.testing.assert_allclose(a.world_to_camera, ref.world_to_camera, atol=1e-12)
        np.testing.assert_allclose(b.world_to_camera, ref.world_to_camera, atol=1e-12)
        np.testing.assert_allclose(a.K, ref.K)
    # 3DGS split: sorted by name, every 8th (index % 8 == 0) is a test view
    assert db.names == [f"img_{i:02d}" for i in range(10)]
    assert db.test_indices == [0, 8] and len(db.train_indices) == 8
    assert db.points is not None and db.points.shape == (40, 3) and db.point_colors.dtype == np.uint8
    assert np.all(db.bounds[0] < db.points.mean(axis=0)) and np.all(db.bounds[1] > db.points.mean(axis=0))
    ref = _rgba(3)[..., :3].astype(np.float32) / 255
    np.testing.assert_allclose(db.images[3].numpy(), ref, atol=1e-6)
    assert len(load_colmap(tmp_path / "b", test_every=0).test_indices) == 0
    assert len(load_cameras(tmp_path / "t" / "sparse" / "0")) == 10


def test_colmap_simple_pinhole_and_downscale(tmp_path: Path) -> None:
    cams, _ = _colmap_fixture(tmp_path, n=3, binary=True, model="SIMPLE_PINHOLE")
    ds = load_colmap(tmp_path, downscale=2)
    assert read_colmap_model(tmp_path / "sparse" / "0").cameras[1].model == "SIMPLE_PINHOLE"
    assert ds.images.shape == (3, H // 2, W // 2, 3)
    np.testing.assert_allclose(ds.cameras[0].K[0, 0], cams[0].K[0, 0] / 2)


@pytest.mark.parametrize("binary", [True, False])
def test_colmap_refuses_other_camera_models_by_name(tmp_path: Path, binary: bool) -> None:
    _, model = _colmap_fixture(tmp_path, n=2, binary=binary)
    model.cameras[1] = ColmapCamera(1, "OPENCV_FISHEYE", W, H, np.array([10.0, 10.0, 8.0, 6.0, 0.1, 0.0, 0.0, 0.0]))
    write_colmap_model(model, tmp_path / "sparse" / "0", binary=binary)
    with pytest.raises(UnsupportedCameraModelError, match="camera 1 uses the COLMAP camera model OPENCV_FISHEYE"):
        load_dataset(tmp_path)
    with pytest.raises(UnsupportedCameraModelError, match="OPENCV_FISHEYE"):
        load_cameras(tmp_path)


def test_colmap_errors(tmp_path: Path) -> None:
    _colmap_fixture(tmp_path / "trunc", n=2, binary=True)
    f = tmp_path / "trunc" / "sparse" / "0" / "images.bin"
    f.write_bytes(f.read_bytes()[:40])
    with pytest.raises(DatasetError, match="images.bin.*ends early"):
        load_dataset(tmp_path / "trunc")
    _colmap_fixture(tmp_path / "missing", n=2, binary=False)
    (tmp_path / "missing" / "images" / "img_01.png").unlink()
    with pytest.raises(DatasetError, match="img_01.png.*not found"):
        load_dataset(tmp_path / "missing")
    _colmap_fixture(tmp_path / "model", n=2, binary=False)
    (tmp_path / "model" / "sparse" / "0" / "cameras.txt").write_text("1 WEIRD 4 4 1 2 3\n")
    with pytest.raises(DatasetError, match="cameras.txt: line 1: unknown COLMAP camera model 'WEIRD'"):
        load_dataset(tmp_path / "model")
    _colmap_fixture(tmp_path / "sizes", n=2, binary=True)
    write_image(np.zeros((H, W + 1, 3), np.uint8), tmp_path / "sizes" / "images" / "img_01.png")
    with pytest.raises(DatasetError, match=r"img_01.png: image is 17x12 but its COLMAP camera \d+ is 16x12"):
        load_dataset(tmp_path / "sizes")


def test_errors_are_roodi_errors() -> None:
    assert issubclass(DatasetError, RoodiError)


def test_estimate_bounds_from_cameras_contains_the_focus() -> None:
    cams = [Camera(look_at(eye, [0.5, 0.0, 0.2]), np.array([[10.0, 0, 8], [0, 10, 6], [0, 0, 1]]), W, H)
            for eye in ([3, 0, 1], [-2, 1, 1], [0, -3, 2], [0.5, 3, 0.5])]
    b = estimate_bounds(cams)
    assert np.all(b[0] < [0.5, 0.0, 0.2]) and np.all(b[1] > [0.5, 0.0, 0.2])
    assert np.all(b[1] - b[0] < 6)


# ------------------------------------------------------------------------------------------- real-capture sizes


def _sized_colmap(root: Path, heights: list[int], width: int = W) -> list[np.ndarray]:
    """A COLMAP fixture with one PINHOLE camera per image, each image its own height (as the undistorter writes)."""
    cams = []
    for i, h in enumerate(heights):
        c = _cams(len(heights), width, h)[i]
        K = c.K.copy()
        K[1, 2] += 0.25 * i  # distinct principal points, so each camera's own intrinsics are checked
        cams.append(Camera(c.world_to_camera, K, width, h, name=c.name))
    names = [f"img_{i:02d}.png" for i in range(len(heights))]
    (root / "sparse" / "0").mkdir(parents=True)
    write_colmap_model(colmap_model_from_cameras(cams, names), root / "sparse" / "0")
    (root / "images").mkdir()
    imgs = []
    for i, (name, h) in enumerate(zip(names, heights)):
        img = _rgba(i, width, h)[..., :3]
        write_image(img, root / "images" / name)
        imgs.append(img)
    return imgs


def test_colmap_images_of_different_sizes_are_cropped_centred(tmp_path: Path) -> None:
    heights = [40, 44, 41]
    imgs = _sized_colmap(tmp_path, heights, width=30)
    model = read_colmap_model(tmp_path / "sparse" / "0")
    ds = load_colmap(tmp_path, test_every=0)
    assert ds.images.shape == (3, 40, 30, 3)
    assert ds.metadata["crop"] == {"size": [30, 40], "images": {"img_01": {"size": [30, 44], "offset": [0, 2]},
                                                                 "img_02": {"size": [30, 41], "offset": [0, 0]}}}
    for i, (img, cam) in enumerate(zip(imgs, ds.cameras)):
        y0 = (heights[i] - 40) // 2
        np.testing.assert_allclose(ds.images[i].numpy(), img[y0:y0 + 40].astype(np.float32) / 255, atol=1e-6)
        ref = model.cameras[model.images[i + 1].camera_id]
        # the principal point moves with the crop; the focal lengths stay
        np.testing.assert_allclose(cam.K[1, 2], ref.params[3] - y0)
        np.testing.assert_allclose(cam.K[0, 0], ref.params[0])
        # the geometry is exact: a 3D point lands on the same image content before and after the crop
        uv, _ = cam.project(np.array([[0.1, -0.2, 0.3]]))
        full = Camera(cam.world_to_camera, np.array([[ref.params[0], 0, ref.params[2]], [0, ref.params[1],
                                                                                         ref.params[3]], [0, 0, 1]]),
                      30, heights[i])
        np.testing.assert_allclose(full.project(np.array([[0.1, -0.2, 0.3]]))[0] - uv, [[0, y0]], atol=1e-9)
    # downscaled: the same crop, then the reduction, decoded one image at a time
    half = load_colmap(tmp_path, 2, test_every=0)
    assert half.images.shape == (3, 20, 15, 3) and half.metadata["downscale"] == 2
    ref = torch.nn.functional.interpolate(ds.images.permute(0, 3, 1, 2), size=(20, 15), mode="area")
    torch.testing.assert_close(half.images, ref.permute(0, 2, 3, 1))
    np.testing.assert_allclose(half.cameras[1].K, ds.cameras[1].with_size(15, 20).K)


def test_colmap_refuses_sizes_too_different_to_crop(tmp_path: Path) -> None:
    _sized_colmap(tmp_path, [40, 50])
    with pytest.raises(DatasetError, match=r"img_00.png: image is 16x40 but .*img_01.png is 16x50; .* at most 10%"):
        load_colmap(tmp_path)


def test_colmap_reads_images_n_folders_when_they_match(tmp_path: Path) -> None:
    _colmap_fixture(tmp_path, n=3, binary=True)
    full = load_colmap(tmp_path, 2, test_every=0)
    (tmp_path / "images_2").mkdir()
    marked = []
    for i in range(3):
        img = np.full((H // 2, W // 2, 3), 40 * (i + 1), np.uint8)  # unlike the reduced originals
        write_image(img, tmp_path / "images_2" / f"img_{i:02d}.png")
        marked.append(img)
    ds = load_colmap(tmp_path, 2, test_every=0)
    assert ds.metadata["images_dir"] == "images_2"
    np.testing.assert_allclose(ds.images[1].numpy(), marked[1] / 255.0, atol=1e-6)
    np.testing.assert_allclose(ds.cameras[1].K, full.cameras[1].K)
    # not every image there: the originals are reduced instead
    (tmp_path / "images_2" / "img_02.png").unlink()
    ds = load_colmap(tmp_path, 2, test_every=0)
    assert ds.metadata["images_dir"] == "images"
    torch.testing.assert_close(ds.images, full.images)


def test_blender_downscale_decodes_to_the_same_result(tmp_path: Path) -> None:
    _blender_fixture(tmp_path, masks=True)
    full, half = load_dataset(tmp_path), load_dataset(tmp_path, 2)
    area = lambda t: torch.nn.functional.interpolate(t.permute(0, 3, 1, 2), size=(H // 2, W // 2), mode="area")
    torch.testing.assert_close(half.images, area(full.images).permute(0, 2, 3, 1))
    torch.testing.assert_close(half.alphas, area(full.alphas[..., None])[:, 0])
    assert half.masks.shape == (5, H // 2, W // 2) and half.masks.dtype == torch.int64


def test_blender_cameras_without_images_when_the_file_states_the_size(tmp_path: Path) -> None:
    fx = _blender_fixture(tmp_path)
    for p in (tmp_path / "train").iterdir():
        p.unlink()
    cams = load_cameras(tmp_path, splits=["train"])
    assert [c.name for c in cams] == ["r_0", "r_1", "r_2"]
    for c, ref in zip(cams, fx["train"][0]):
        assert (c.width, c.height) == (W, H)
        np.testing.assert_allclose(c.K, ref.K)
    with pytest.raises(DatasetError, match="frame 0 image not found .*r_0.png"):
        load_dataset(tmp_path)


@pytest.mark.parametrize("model,params", [
    ("OPENCV", [60.0, 62.0, 40.5, 29.0, -0.18, 0.03, 0.002, -0.001]),
    ("SIMPLE_RADIAL", [60.0, 40.0, 30.0, 0.12]),
    ("FULL_OPENCV", [60.0, 60.0, 40.0, 30.0, -0.1, 0.02, 0.0, 0.001, 0.0, 0.05, 0.0, 0.0]),
])
def test_colmap_distorted_cameras_are_undistorted(tmp_path: Path, model: str, params: list[float]) -> None:
    import cv2

    from roodi_toolkit.io.colmap import _distortion, _opencv_k

    w, h = 80, 60
    cam = ColmapCamera(1, model, w, h, np.array(params))
    K, dist = _distortion(cam)
    # a photo through the distorting lens of a smooth pattern painted on the normalised image plane
    pattern = lambda x, y: 0.5 + 0.4 * np.sin(3 * x) * np.cos(2 * y)
    px = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(px, _opencv_k(K), dist).reshape(h, w, 2)
    photo = np.repeat(pattern(rays[..., 0], rays[..., 1])[..., None], 3, axis=2)
    ref_cam = _cams(1, w, h)[0]
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    m = colmap_model_from_cameras([ref_cam], ["a.png"])
    m.cameras[1] = cam
    write_colmap_model(m, tmp_path / "sparse" / "0")
    (tmp_path / "images").mkdir()
    write_image(np.round(photo[..., 0] * 65535).astype(np.uint16), tmp_path / "images" / "a.png")  # 16-bit grey
    ds = load_colmap(tmp_path, test_every=0)
    loaded = ds.cameras[0]
    assert (loaded.width, loaded.height) == (w, h) and load_cameras(tmp_path)[0].K.tolist() == loaded.K.tolist()
    # every loaded pixel shows the pattern at its pinhole ray
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    x = (u - loaded.K[0, 2]) / loaded.K[0, 0]
    y = (v - loaded.K[1, 2]) / loaded.K[1, 1]
    err = np.abs(ds.images[0, ..., 0].numpy() - pattern(x, y))
    assert err[2:-2, 2:-2].max() < 0.005, err.max()
    # a click in the distorted photo lands where the same ray is in the loaded image
    from roodi_toolkit.io.dataset import to_loaded_pixel

    for qx, qy in ((10.5, 7.5), (70.5, 50.5), (40.5, 30.5)):
        lx, ly = to_loaded_pixel(ds, "a", qx, qy)
        ray = rays[int(qy), int(qx)]
        np.testing.assert_allclose([(lx - loaded.K[0, 2]) / loaded.K[0, 0], (ly - loaded.K[1, 2]) / loaded.K[1, 1]],
                                   ray, atol=1e-6)
    # a pinhole model of the distorted photo would be off by far more
    pinhole = np.abs(photo[..., 0] - pattern((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]))
    assert pinhole.max() > max(0.02, 10 * err[2:-2, 2:-2].max()), (pinhole.max(), err.max())


@pytest.mark.parametrize("case,needle", [
    ("missing image", "img_01.png: image of COLMAP image 2 ('img_01.png') not found"),
    ("unknown model", "cameras.txt: line 1: unknown COLMAP camera model 'WEIRD'"),
    ("mismatched ids", "image 'img_00.png' refers to camera 7, which is not in the model"),
    ("fisheye", "camera 1 uses the COLMAP camera model OPENCV_FISHEYE"),
])
def test_cli_train_refuses_a_bad_colmap_folder_in_one_line(tmp_path: Path, run_cli, case: str, needle: str) -> None:
    _colmap_fixture(tmp_path / "data", n=3, binary=False)
    sparse = tmp_path / "data" / "sparse" / "0"
    if case == "missing image":
        (tmp_path / "data" / "images" / "img_01.png").unlink()
    elif case == "unknown model":
        (sparse / "cameras.txt").write_text("1 WEIRD 4 4 1 2 3\n")
    elif case == "mismatched ids":
        text = (sparse / "images.txt").read_text().splitlines()
        i = next(k for k, line in enumerate(text) if line.endswith("img_00.png"))
        parts = text[i].split()
        parts[8] = "7"
        text[i] = " ".join(parts)
        (sparse / "images.txt").write_text("\n".join(text) + "\n")
    else:
        (sparse / "cameras.txt").write_text(f"1 OPENCV_FISHEYE {W} {H} 10 10 8 6 0.1 0 0 0\n")
    res = run_cli("train", tmp_path / "data", tmp_path / "out", "--iterations", "1", "-q")
    assert res.exit_code == 1 and needle in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "out").exists()
