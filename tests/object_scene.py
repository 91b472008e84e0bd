"""A tiny scene of Gaussians with known objects, rendered into a posed dataset with exact instance masks.

Two objects (a red ball, id 1, and a blue box, id 2) of surface Gaussians on a grey ground (id 0), seen by an orbit
of cameras. The images are rendered from the Gaussians themselves and the masks are the argmax of the rendered
one-hot object ids, so a perfect distillation exists and every Gaussian's true object is known.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from roodi_toolkit.cameras import orbit_cameras
from roodi_toolkit.io.blender import write_blender_transforms
from roodi_toolkit.io.dataset import Dataset
from roodi_toolkit.io.files import write_image, write_json
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.io.ply import write_ply
from roodi_toolkit.render.renderer import render_cloud


def object_cloud(seed: int = 0) -> tuple[GaussianCloud, np.ndarray]:
    """Return the cloud and each Gaussian's object id ``[N]``."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(260, 3))
    ball = np.array([-0.45, 0.0, 0.0]) + 0.3 * d / np.linalg.norm(d, axis=1, keepdims=True)
    u = rng.uniform(-1, 1, size=(300, 3))
    face = rng.integers(0, 3, 300)
    u[np.arange(300), face] = np.sign(u[np.arange(300), face])
    box = np.array([0.45, 0.0, -0.05]) + u * np.array([0.22, 0.22, 0.25])
    g = rng.uniform(-1.4, 1.4, size=(700, 2))
    ground = np.concatenate([g, np.full((700, 1), -0.32)], axis=1)
    means = np.concatenate([ball, box, ground])
    ids = np.concatenate([np.full(260, 1), np.full(300, 2), np.zeros(700, int)])
    colors = np.array([[0.6, 0.6, 0.55], [0.9, 0.15, 0.1], [0.1, 0.25, 0.9]])[ids]
    colors = np.clip(colors + rng.normal(0, 0.03, colors.shape), 0, 1)
    scales = np.where(ids[:, None] == 0, 0.09, 0.055) * np.ones((len(means), 3))
    cloud = GaussianCloud.from_activated(means, scales=scales, opacities=np.full(len(means), 0.95), rgb=colors)
    return cloud, ids


def object_dataset(size: int = 32, views: int = 12, seed: int = 0) -> tuple[Dataset, GaussianCloud, np.ndarray]:
    """Return the dataset (images on white, masks), the cloud and its Gaussians' ids."""
    cloud, ids = object_cloud(seed)
    cams = orbit_cameras((0, 0, -0.1), 3.0, views, elevation_deg=35, width=size, height=size, fov_x_deg=45)
    cams = [c.__class__(c.world_to_camera, c.K, c.width, c.height, c.near, c.far, f"r_{i:03d}")
            for i, c in enumerate(cams)]
    onehot = np.eye(3, dtype=np.float64)[ids]
    cloud_ids = GaussianCloud(cloud.means, cloud.quats_wxyz, cloud.log_scales, cloud.opacity_logits, cloud.sh_dc,
                              cloud.sh_rest, {f"id{k}": onehot[:, k] for k in range(3)})
    images, masks = [], []
    for cam in cams:
        out = render_cloud(cloud_ids, cam, background=(1.0, 1.0, 1.0), features=["id0", "id1", "id2"])
        images.append(out.rgb.clamp(0, 1))
        m = out.features.argmax(-1)
        m[out.alpha[..., 0] < 0.5] = 0
        masks.append(m)
    ds = Dataset(images=torch.stack(images), cameras=cams, splits=["train"] * views, background=(1.0, 1.0, 1.0),
                 bounds=np.array([[-1.5, -1.5, -0.4], [1.5, 1.5, 0.4]]), masks=torch.stack(masks).to(torch.int64))
    return ds, cloud, ids


def write_object_scene(root: Path, size: int = 32, views: int = 12) -> tuple[Path, Path, np.ndarray]:
    """Write the dataset (Blender format, masks via mask_path) and a model folder as ``roodi-toolkit train`` would;
    return (data_dir, model_dir, ids)."""
    ds, cloud, ids = object_dataset(size, views)
    data, model = root / "data", root / "model"
    (data / "train" / "masks").mkdir(parents=True)
    for cam, img, m in zip(ds.cameras, ds.images, ds.masks):
        write_image(img.numpy(), data / "train" / f"{cam.name}.png")
        write_image(m.numpy().astype(np.uint8), data / "train" / "masks" / f"{cam.name}.png")
    write_blender_transforms(data / "transforms_train.json", ds.cameras, [f"train/{c.name}" for c in ds.cameras],
                             extra={"background": [1.0, 1.0, 1.0], "scene_bounds": ds.bounds.tolist()},
                             frame_extra=[{"mask_path": f"train/masks/{c.name}.png"} for c in ds.cameras])
    (model / "point_cloud" / "iteration_7").mkdir(parents=True)
    (model / "point_cloud" / "iteration_3").mkdir(parents=True)
    write_ply(cloud, model / "point_cloud" / "iteration_7" / "point_cloud.ply")
    write_ply(cloud.select(np.arange(10)), model / "point_cloud" / "iteration_3" / "point_cloud.ply")
    write_json({"data_dir": str(data), "downscale": 1, "holdout_every": 4}, model / "cfg.json")
    return data, model, ids


def tree_digest(root: Path) -> dict[str, tuple[int, str]]:
    """Return every file under ``root`` (relative path -> size, SHA-256) and every folder (-> None): equal digests
    mean a byte-identical tree, nothing added or removed."""
    import hashlib

    out: dict = {}
    for p in sorted(Path(root).rglob("*")):
        rel = p.relative_to(root).as_posix()
        out[rel] = (p.stat().st_size, hashlib.sha256(p.read_bytes()).hexdigest()) if p.is_file() else None
    return out
