"""Scenes trained by other tools as --model (roodi_toolkit.io.model.open_model, io.other_models): an Inria output
folder checked against its data's cameras, a gsplat checkpoint read without unpickling code and its normalised world
undone, a nerfstudio export moved back by its dataparser_transforms.json, a bare splat file with its data folder;
each through extract / distill / select / prune / render / evaluate / convert, and refused, with the reason, when
model and data are in different frames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from roodi_toolkit.errors import ConfigError, RoodiError
from roodi_toolkit.io.model import ModelError, open_model
from roodi_toolkit.io.ply import read_ply, write_ply
from roodi_toolkit.similarity import Similarity, euler_rotation, transform_cloud

from ..object_scene import object_cloud, tree_digest, write_object_scene

FAST = ("--no-inpaint", "--distill-iterations", "20", "-q")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The object scene: a Blender dataset with masks (ball = 1, box = 2) and its true cloud."""
    root = tmp_path_factory.mktemp("others")
    data, _, _ = write_object_scene(root, size=24, views=8)
    cloud, _ = object_cloud()
    return root, data, cloud


def write_inria(root: Path, data: Path, cloud, *, shift: float = 0.0, **args) -> Path:
    """Write an Inria output folder for ``cloud`` trained on ``data``: point_cloud/iteration_30000, cfg_args and
    cameras.json as the Inria code writes them (``camera_to_JSON``: the camera-to-world rotation and centre)."""
    from roodi_toolkit.io.dataset import load_cameras

    (root / "point_cloud" / "iteration_30000").mkdir(parents=True)
    write_ply(cloud, root / "point_cloud" / "iteration_30000" / "point_cloud.ply")
    fields = {"sh_degree": 0, "source_path": str(data), "model_path": str(root), "images": "images",
              "resolution": -1, "white_background": True, "data_device": "cuda", "eval": False, **args}
    (root / "cfg_args").write_text("Namespace(" + ", ".join(f"{k}={v!r}" for k, v in fields.items()) + ")")
    entries = []
    for i, cam in enumerate(load_cameras(data)):
        c2w = np.linalg.inv(cam.world_to_camera)
        entries.append({"id": i, "img_name": cam.name, "width": cam.width, "height": cam.height,
                        "position": (c2w[:3, 3] + shift).tolist(), "rotation": [r.tolist() for r in c2w[:3, :3]],
                        "fy": cam.K[1, 1], "fx": cam.K[0, 0]})
    (root / "cameras.json").write_text(json.dumps(entries))
    return root


# ------------------------------------------------------------------------------------------------------------ Inria
def test_inria_folder_opens_with_its_record_and_extracts(scene, tmp_path, run_cli) -> None:
    root, data, cloud = scene
    inria = write_inria(tmp_path / "inria", data, cloud, eval=True)
    model = open_model(inria)
    assert model.kind == "inria" and model.iteration == 30000 and Path(model.config["data_dir"]) == data
    assert model.config["holdout_every"] == 8 and model.config["downscale"] == 1.0
    assert model.config["background"] == [1.0, 1.0, 1.0]
    np.testing.assert_array_equal(model.read_cloud().means, cloud.means)
    before = tree_digest(inria), tree_digest(data)
    res = run_cli("extract", tmp_path / "out", "--model", inria, "--object", "1", *FAST)  # data from cfg_args
    assert res.exit_code == 0, res.stderr
    assert "model: Inria output folder, iteration 30000" in res.stdout
    assert "cameras.json agrees with 8 of the dataset's cameras" in res.stdout
    obj = read_ply(tmp_path / "out" / "object_1" / "object.ply")
    assert 0 < len(obj) < len(cloud)
    assert (tree_digest(inria), tree_digest(data)) == before


def test_inria_cameras_in_another_frame_are_refused(scene, tmp_path, run_cli) -> None:
    root, data, cloud = scene
    inria = write_inria(tmp_path / "inria", data, cloud, shift=0.5)
    with pytest.raises(ModelError, match=r"camera r_\d+ is 0.\d+ of the cameras' spread from the dataset's .* "
                                         "different frames"):
        open_model(inria)
    res = run_cli("distill", inria, data, tmp_path / "d", "-q")
    assert res.exit_code == 1 and "cameras.json" in res.stderr and "different frames" in res.stderr
    assert not (tmp_path / "d").exists()


def test_inria_record_parsing_is_literal_only(tmp_path) -> None:
    from roodi_toolkit.io.other_models import inria_settings, read_cfg_args

    (tmp_path / "cfg_args").write_text("Namespace(source_path=__import__('os').getcwd(), eval=True)")
    with pytest.raises(ModelError, match="'source_path' is not a literal value"):
        read_cfg_args(tmp_path / "cfg_args")
    (tmp_path / "cfg_args").write_text("print('hello')")
    with pytest.raises(ModelError, match="not an Inria cfg_args file"):
        read_cfg_args(tmp_path / "cfg_args")
    # resolution: 1/2/4/8 as given, -1 reduces photos wider than 1600 px, a number is a target width
    assert inria_settings(tmp_path, {"resolution": 4}, 4000)["downscale"] == 4.0
    assert inria_settings(tmp_path, {"resolution": -1}, 4000)["downscale"] == 2.5
    assert inria_settings(tmp_path, {"resolution": -1}, 1000)["downscale"] == 1.0
    assert inria_settings(tmp_path, {"resolution": 500, "images": "images_2"}, 2000)["downscale"] == 4.0


def test_inria_ply_prunes_with_its_photos_and_renders_upright(scene, tmp_path, run_cli) -> None:
    root, data, cloud = scene
    inria = write_inria(tmp_path / "inria", data, cloud)
    ply = inria / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    res = run_cli("prune", ply, tmp_path / "clean.ply", "--report", tmp_path / "r.json", "-q")
    assert res.exit_code == 0, res.stderr
    assert "photo check on" in json.loads((tmp_path / "r.json").read_text())["mode_reason"]
    res = run_cli("render", ply, tmp_path / "r", "--up", "auto", "--orbit", "1", "--size", "8x8")
    assert res.exit_code == 0, res.stderr
    assert "the mean up of the model's training cameras" in res.stderr
    res = run_cli("render", ply, tmp_path / "views", "--cameras", inria / "cameras.json", "-q")  # its own cameras
    assert res.exit_code == 0, res.stderr
    assert len(list((tmp_path / "views").glob("r_*.png"))) == 8


# ----------------------------------------------------------------------------------------------------------- gsplat
@pytest.fixture(scope="module")
def colmap_scene(scene):
    """The object scene as a COLMAP capture (PNG photos, its cloud's means as the SfM points) and its masks."""
    from roodi_toolkit.io.colmap import ColmapPoints, colmap_model_from_cameras, write_colmap_model
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.files import write_image

    root, data, cloud = scene
    ds = load_dataset(data)
    col = root / "colmap"
    (col / "images").mkdir(parents=True)
    (col / "masks").mkdir()
    (col / "sparse" / "0").mkdir(parents=True)
    for cam, img, m in zip(ds.cameras, ds.images, ds.masks):
        write_image(img.numpy(), col / "images" / f"{cam.name}.png")
        write_image(m.numpy().astype(np.uint8), col / "masks" / f"{cam.name}.png")
    n = len(cloud)
    pts = ColmapPoints(ids=np.arange(1, n + 1), xyz=cloud.means.astype(np.float64),
                       rgb=np.clip(cloud.rgb * 255, 0, 255).astype(np.uint8), errors=np.zeros(n),
                       tracks=[np.zeros((0, 2), np.int64)] * n)
    write_colmap_model(colmap_model_from_cameras(ds.cameras, [f"{c.name}.png" for c in ds.cameras], pts),
                       col / "sparse" / "0")
    return col


GSPLAT_YML = """data_dir: {data}
data_factor: 1
normalize_world_space: true
test_every: 8
sh_degree: 3
strategy: !!python/object:gsplat.strategy.default.DefaultStrategy
  absgrad: false
  refine_every: 100
render_traj_path: interp
"""


def write_gsplat(result: Path, cloud, to_ckpt: Similarity, data: Path | None, *, extra: dict | None = None) -> Path:
    """Write a gsplat result folder: cfg.yml (with gsplat's Python tags) and ckpts/ckpt_6999_rank0.pt holding
    ``{"step", "splats"}`` of ``cloud`` moved into the checkpoint's frame."""
    moved = transform_cloud(cloud, to_ckpt)
    (result / "ckpts").mkdir(parents=True)
    if data is not None:
        (result / "cfg.yml").write_text(GSPLAT_YML.format(data=data))
    splats = {"means": torch.from_numpy(moved.means), "quats": torch.from_numpy(moved.quats_wxyz),
              "scales": torch.from_numpy(moved.log_scales), "opacities": torch.from_numpy(moved.opacity_logits),
              "sh0": torch.from_numpy(moved.sh_dc[:, None, :]), "shN": torch.from_numpy(moved.sh_rest)}
    torch.save({"step": 6999, "splats": splats, **(extra or {})}, result / "ckpts" / "ckpt_6999_rank0.pt")
    return result


def test_gsplat_normalisation_is_gsplats(colmap_scene) -> None:
    """The documented properties of gsplat's normalize.py: after similarity_from_cameras the cameras' mean up is
    -y and their median distance from the focus 1; after align_principal_axes the points' median is the origin and
    their principal axes are x, y, z in decreasing spread."""
    from roodi_toolkit.cameras import invert_rigid
    from roodi_toolkit.io.colmap import read_colmap_model
    from roodi_toolkit.io.gsplat import _align_principal_axes, _similarity_from_cameras, gsplat_frames

    model = read_colmap_model(colmap_scene / "sparse" / "0")
    c2w = np.stack([invert_rigid(im.world_to_camera()) for im in model.images.values()])
    T1 = _similarity_from_cameras(c2w)
    s = np.cbrt(np.linalg.det(T1[:3, :3]))
    ups = (T1[:3, :3] / s @ (c2w[:, :3, :3] @ np.array([0.0, -1.0, 0.0])).mean(0))
    np.testing.assert_allclose(ups / np.linalg.norm(ups), [0.0, -1.0, 0.0], atol=1e-9)
    centres = c2w[:, :3, 3] @ T1[:3, :3].T + T1[:3, 3]
    assert np.median(np.linalg.norm(centres, axis=1)) == pytest.approx(1.0, abs=1e-9)
    p1 = model.points.xyz.astype(np.float32) @ T1[:3, :3].T + T1[:3, 3]
    T2 = _align_principal_axes(p1)
    np.testing.assert_allclose(T2[:3, :3] @ np.median(p1, axis=0) + T2[:3, 3], 0.0, atol=1e-9)
    pts = p1 @ T2[:3, :3].T + T2[:3, 3]
    cov = np.cov(pts, rowvar=False)
    assert np.abs(cov - np.diag(np.diag(cov))).max() < 1e-9 and cov[0, 0] >= cov[1, 1] >= cov[2, 2]
    np.testing.assert_allclose(gsplat_frames(colmap_scene / "sparse" / "0")[0].matrix(), T2 @ T1, atol=1e-12)


def test_gsplat_checkpoint_opens_in_the_data_frame_and_distils(scene, colmap_scene, tmp_path, run_cli) -> None:
    from roodi_toolkit.io.gsplat import gsplat_frames

    _, _, cloud = scene
    to_ckpt = gsplat_frames(colmap_scene / "sparse" / "0")[0]
    result = write_gsplat(tmp_path / "results" / "obj", cloud, to_ckpt, colmap_scene)
    for path in (result, result / "ckpts", result / "ckpts" / "ckpt_6999_rank0.pt"):
        model = open_model(path)
        assert model.kind == "gsplat" and model.iteration == 6999 and model.config["holdout_every"] == 8
        back = model.read_cloud()
        np.testing.assert_allclose(back.means, cloud.means, atol=1e-5)
        np.testing.assert_allclose(back.rotations(), cloud.rotations(), atol=1e-5)
        np.testing.assert_allclose(back.log_scales, cloud.log_scales, atol=1e-5)
    res = run_cli("distill", result / "ckpts" / "ckpt_6999_rank0.pt", colmap_scene, tmp_path / "d", "--masks",
                  colmap_scene / "masks", "--iterations", "20", "-q")
    assert res.exit_code == 0, res.stderr
    record = json.loads((tmp_path / "d" / "distill.json").read_text())
    assert record["model_kind"] == "gsplat" and record["model_to_data"] is not None
    res = run_cli("select", tmp_path / "d", "--object", "1", tmp_path / "ball.ply")
    assert res.exit_code == 0, res.stderr
    ball = read_ply(tmp_path / "ball.ply")  # in the data's frame: around the ball's centre (-0.45, 0, 0)
    assert len(ball) > 50 and np.abs(np.median(ball.means, axis=0) - [-0.45, 0.0, 0.0]).max() < 0.1
    res = run_cli("convert", result, tmp_path / "scene.ply")  # data from cfg.yml
    assert res.exit_code == 0, res.stderr
    np.testing.assert_allclose(read_ply(tmp_path / "scene.ply").means, cloud.means, atol=1e-5)


class Gadget:
    """A class a malicious checkpoint pickles: loading it must not run anything."""

    def __reduce__(self):
        return (print, ("code ran",))


def test_gsplat_checkpoint_with_pickled_code_is_refused(scene, colmap_scene, tmp_path, capsys) -> None:
    _, _, cloud = scene
    result = write_gsplat(tmp_path / "r", cloud, Similarity(), colmap_scene, extra={"gadget": Gadget()})
    with pytest.raises(ModelError, match="not a gsplat checkpoint that loads as plain tensors"):
        open_model(result)
    assert "code ran" not in capsys.readouterr().out


def test_gsplat_wrong_data_is_refused(scene, colmap_scene, tmp_path) -> None:
    _, _, cloud = scene
    far = Similarity(translation=np.array([40.0, 0.0, 0.0]))  # a scene the data's cameras do not see
    result = write_gsplat(tmp_path / "r", transform_cloud(cloud, far), Similarity(), colmap_scene)
    with pytest.raises(ModelError, match="normalisation .* undone, only 0% of its Gaussians lie in view"):
        open_model(result)
    no_cfg = write_gsplat(tmp_path / "bare", cloud, Similarity(), None)
    with pytest.raises(ModelError, match="no cfg.yml beside its ckpts folder names the data; give DATA_DIR"):
        open_model(no_cfg)


def test_photos_pick_between_two_frames(scene, colmap_scene) -> None:
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.model import ModelFolder
    from roodi_toolkit.pipeline.model_frame import settle_model_frame
    from roodi_toolkit.run.distill import check_model_frame

    root, data, cloud = scene
    path = root / "true_scene.ply"
    write_ply(cloud, path)
    flip = Similarity(rotation=np.diag([1.0, -1.0, -1.0]))
    ds = load_dataset(colmap_scene)
    for frames, pick in (([flip, Similarity()], 1), ([Similarity(), flip], 0)):
        model = ModelFolder(path, path, 0, {"holdout_every": 0}, kind="gsplat", to_data=frames[0], frames=frames)
        report = settle_model_frame(model, cloud, ds)  # the scene in memory, as its file holds it
        assert model.to_data is frames[pick] and model.frames == []
        assert report["model_check_error"] < 0.1 * report["model_check_empty"]
    wrong = ModelFolder(path, path, 0, {}, kind="splat", to_data=Similarity(scale=0.37))  # another scene's size
    with pytest.raises(ConfigError, match="explains their photos less than 3 dB better than an empty picture"):
        check_model_frame(wrong, ds)  # the run layer reads the file for it
    absent = root / "absent.ply"  # a scene this toolkit trained is not checked: its file is not even read
    assert check_model_frame(ModelFolder(absent, absent, 0, {}), ds) == {}


# ------------------------------------------------------------------------------------------------------- nerfstudio
def _as_nerfstudio(data: Path, out: Path, applied: np.ndarray) -> Path:
    """Write the Blender dataset as a nerfstudio capture whose poses were turned by ``applied`` (3x4)."""
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.files import write_image
    from roodi_toolkit.cameras import w2c_to_opengl_c2w

    ds = load_dataset(data)
    (out / "images").mkdir(parents=True)
    A = np.eye(4)
    A[:3] = applied
    frames = []
    for cam, img in zip(ds.cameras, ds.images):
        write_image(img.numpy(), out / "images" / f"{cam.name}.png")
        frames.append({"file_path": f"images/{cam.name}.png",
                       "transform_matrix": (A @ w2c_to_opengl_c2w(cam.world_to_camera)).tolist()})
    c = ds.cameras[0]
    meta = {"fl_x": c.K[0, 0], "fl_y": c.K[1, 1], "cx": c.K[0, 2], "cy": c.K[1, 2], "w": c.width, "h": c.height,
            "applied_transform": applied.tolist(), "frames": frames}
    (out / "transforms.json").write_text(json.dumps(meta))
    return out


def test_nerfstudio_export_moves_back_with_its_dataparser_transforms(scene, tmp_path, run_cli) -> None:
    root, data, cloud = scene
    applied = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]])  # ns-process-data's
    ns = _as_nerfstudio(data, tmp_path / "capture", applied)
    # nerfstudio: oriented, centred, scaled poses; its dataparser_transforms.json holds transform @ applied
    orient = Similarity(euler_rotation(10, -20, 35), np.array([0.2, -0.1, 0.3]))
    scale = 0.37
    A = Similarity.from_matrix(applied)
    export = transform_cloud(transform_cloud(cloud, A), orient.then(Similarity(scale=scale)))
    write_ply(export, tmp_path / "splat.ply")
    (tmp_path / "dataparser_transforms.json").write_text(json.dumps(
        {"transform": (orient.matrix() @ A.matrix())[:3].tolist(), "scale": scale}))
    model = open_model(tmp_path / "splat.ply", ns, dataparser_transforms=tmp_path / "dataparser_transforms.json")
    np.testing.assert_allclose(model.read_cloud().means, transform_cloud(cloud, A).means, atol=1e-5)
    # the same export against the original (untransformed) data: the data parser's transform alone is undone
    back = open_model(tmp_path / "splat.ply", data, dataparser_transforms=tmp_path / "dataparser_transforms.json")
    np.testing.assert_allclose(back.read_cloud().means, cloud.means, atol=1e-5)
    res = run_cli("extract", ns, tmp_path / "out", "--model", tmp_path / "splat.ply", "--dataparser-transforms",
                  tmp_path / "dataparser_transforms.json", "--click", "6,12", "--view", "r_000", *FAST)
    assert res.exit_code == 0, res.stderr
    # without its transform the export is in another frame: the photos say so
    res = run_cli("distill", tmp_path / "splat.ply", ns, tmp_path / "d", "--segmenter", "click", "--click",
                  "r_000:6,12", "-q")
    assert res.exit_code == 1 and ("different frames" in res.stderr or "less than 3 dB better than an empty picture"
                                   in res.stderr), res.stderr
    res = run_cli("convert", tmp_path / "splat.ply", tmp_path / "back.ply", "--data", ns, "--dataparser-transforms",
                  tmp_path / "dataparser_transforms.json")
    assert res.exit_code == 0, res.stderr
    np.testing.assert_allclose(read_ply(tmp_path / "back.ply").means, transform_cloud(cloud, A).means, atol=1e-5)


# ------------------------------------------------------------------------------------------------- bare splat files
def test_bare_splat_file_as_model_with_its_data(scene, tmp_path, run_cli) -> None:
    root, data, cloud = scene
    from roodi_toolkit.io.splat import write_cloud

    write_cloud(cloud, tmp_path / "scene.spz")
    res = run_cli("extract", tmp_path / "out", "--model", tmp_path / "scene.spz", "--object", "1", *FAST)
    assert res.exit_code == 1 and "needs the data folder it was trained on; give DATA_DIR" in res.stderr
    res = run_cli("extract", data, tmp_path / "out", "--model", tmp_path / "scene.spz", "--object", "1", *FAST)
    assert res.exit_code == 0, res.stderr
    assert len(read_ply(tmp_path / "out" / "object_1" / "object.ply")) > 0
    far = transform_cloud(cloud, Similarity(translation=np.array([0.0, 0.0, 50.0])))
    write_cloud(far, tmp_path / "far.ply")
    res = run_cli("distill", tmp_path / "far.ply", data, tmp_path / "d", "-q")
    assert res.exit_code == 1 and "only 0% of its Gaussians lie in view of the cameras" in res.stderr


def test_evaluate_takes_a_model_from_another_tool(tmp_path, run_cli) -> None:
    from roodi_toolkit.gaussians import GaussianCloud
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.synth.scene import SceneSettings, make_scene

    gen = tmp_path / "gen"
    record = make_scene(gen, "kitchen", seed=3, settings=SceneSettings(width=16, height=16, train_views=3,
                                                                         test_views=2, supersample=1, n_objects=5,
                                                                         n_targets=1))
    target = int(record["targets"][0]["id"])
    lo, hi = load_dataset(gen).bounds
    rng = np.random.default_rng(0)
    blob = GaussianCloud.from_activated((lo + hi) / 2 + rng.normal(0, 0.05, (200, 3)), scales=np.full((200, 3), 0.02),
                                        opacities=np.full(200, 0.8), rgb=np.full((200, 3), 0.6))
    result = write_gsplat(tmp_path / "gs", blob, Similarity(), gen)
    (result / "cfg.yml").write_text(GSPLAT_YML.format(data=gen).replace("normalize_world_space: true",
                                                                         "normalize_world_space: false"))
    res = run_cli("evaluate", result / "ckpts" / "ckpt_6999_rank0.pt", gen, "--object", target, "-q")
    assert res.exit_code == 0, res.stderr
    assert "PSNR" in res.stdout
    res = run_cli("evaluate", tmp_path / "nothing", gen, "--object", target, "-q")
    assert res.exit_code == 1 and "nothing" in res.stderr
