"""SAM2 video propagation of clicks (positive, and negative ones on what is not the target) over the views of a
posed dataset (the paper's segmentation).

The views are not a video, so they are ordered into one: starting at the clicked view, each next frame is the
nearest remaining camera (a greedy chain over camera centres), which keeps consecutive frames close as SAM2's memory
expects. The frames are written as JPEGs (what ``SAM2VideoPredictor.init_state`` reads), the clicks are added on
frame 0 as positive points of object 1, and ``propagate_in_video`` gives a mask per frame (logits > 0).

``sam2`` is imported only when a segmentation runs; without it the plugin reports how to install it.
"""

from __future__ import annotations

import importlib.util
import tempfile
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch

from roodi_toolkit.cameras import Camera
from roodi_toolkit.io.dataset import Dataset
from roodi_toolkit.errors import ConfigError, PluginError
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.progress import ProgressFactory, null_progress
from roodi_toolkit.pipeline.segment import Segmenter, SegmentPrompt, ViewMasks, check_clicks

INSTALL_HINT = ("the sam2 package is not installed: pip install 'roodi-sam2[sam2]' (or install SAM2 from "
                "https://github.com/facebookresearch/sam2), and download a checkpoint such as "
                "sam2.1_hiera_tiny.pt yourself")


def frame_order(cameras: Sequence[Camera], first: int) -> list[int]:
    """Return all view indices as a video: ``first``, then repeatedly the nearest remaining camera centre.

    Example:
        >>> from roodi_toolkit.cameras import look_at, intrinsics_from_fov
        >>> K = intrinsics_from_fov(1.0, 8, 8)
        >>> cams = [Camera(look_at((x, -5, 1), (0, 0, 0)), K, 8, 8) for x in (0.0, 3.0, 1.0, 2.0)]
        >>> frame_order(cams, 0)
        [0, 2, 3, 1]
    """
    centres = np.stack([c.center for c in cameras])
    order = [first]
    left = set(range(len(cameras))) - {first}
    while left:
        last = centres[order[-1]]
        nxt = min(left, key=lambda i: (float(np.linalg.norm(centres[i] - last)), i))
        order.append(nxt)
        left.remove(nxt)
    return order


def build_predictor(config: str, checkpoint: str, device: str) -> Any:
    """Return ``sam2.build_sam.build_sam2_video_predictor(config, checkpoint, device=device)``.

    Raises:
        PluginError: sam2 is not installed (with the install hint) or the model cannot be built.
    """
    if importlib.util.find_spec("sam2") is None:
        raise PluginError(INSTALL_HINT)
    from sam2.build_sam import build_sam2_video_predictor

    try:
        return build_sam2_video_predictor(config, checkpoint, device=device)
    except Exception as exc:  # noqa: BLE001 - hydra/config/checkpoint errors, reported with the paths
        raise PluginError(f"SAM2 could not build the model from config {config!r} and checkpoint {checkpoint!r}: "
                          f"{type(exc).__name__}: {exc}") from exc


class SAM2Segmenter(Segmenter):
    """SAM2 video predictor driven by clicks in one view.

    Args:
        checkpoint: local path of a SAM2 checkpoint (``.pt``); nothing is downloaded.
        config: the SAM2 model config name matching the checkpoint (default: SAM2.1 hiera tiny).
        device: torch device for SAM2 (``cpu`` works, slowly; ``cuda`` where available).
        predictor_factory: ``(config, checkpoint, device) -> predictor``; default :func:`build_predictor` (tests
            pass a fake here).
    """

    name = "sam2"

    def __init__(self, checkpoint: str | None = None, config: str = "configs/sam2.1/sam2.1_hiera_t.yaml",
                 device: str = "cpu", predictor_factory: Optional[Callable[[str, str, str], Any]] = None) -> None:
        self.checkpoint = checkpoint
        self.config = config
        self.device = device
        self.predictor_factory = predictor_factory or build_predictor

    @classmethod
    def available(cls) -> tuple[bool, str]:
        if importlib.util.find_spec("sam2") is None:
            return False, INSTALL_HINT
        return True, ""

    @classmethod
    def status(cls) -> tuple[str, str]:
        """Return ``("needs a package", ...)`` without sam2, else ``("needs weights", ...)``: the checkpoint is never
        downloaded and comes with each run (``--segmenter-option checkpoint=PATH``)."""
        if importlib.util.find_spec("sam2") is None:
            return "needs a package", INSTALL_HINT
        return "needs weights", ("give a local SAM2 checkpoint with each run: --segmenter-option "
                                 "checkpoint=PATH/sam2.1_hiera_tiny.pt")

    def segment(self, dataset: Dataset, prompt: SegmentPrompt, *, scene: Optional[GaussianCloud] = None,
                progress: ProgressFactory = null_progress) -> ViewMasks:
        """Return binary masks (1 = the clicked object) of every view, propagated by SAM2 from the clicked view.

        Raises:
            ConfigError: bad clicks, or no / a missing checkpoint.
            PluginError: sam2 missing, or its output is not one mask per frame of the view size.
        """
        from roodi_toolkit.io.files import write_image

        v0 = check_clicks(dataset, prompt.clicks)
        if not self.checkpoint:
            raise ConfigError("the sam2 segmenter needs a local checkpoint: --option checkpoint=PATH/sam2.1_hiera_tiny.pt")
        if not Path(self.checkpoint).is_file():
            raise ConfigError(f"{self.checkpoint}: SAM2 checkpoint not found")
        predictor = self.predictor_factory(self.config, str(self.checkpoint), self.device)
        order = frame_order(dataset.cameras, v0)
        H, W = dataset.height, dataset.width
        out = np.zeros((len(dataset), H, W), dtype=np.int64)
        seen = set()
        points = np.array([[c.x, c.y] for c in prompt.clicks], dtype=np.float32)
        labels = np.array([1 if c.positive else 0 for c in prompt.clicks], dtype=np.int32)  # SAM: 0 = negative
        with tempfile.TemporaryDirectory(prefix="roodi-sam2-") as tmp:
            for k, v in enumerate(order):
                write_image(dataset.images[v].numpy(), Path(tmp) / f"{k:05d}.jpg")
            with torch.inference_mode(), progress(total=len(order), desc="sam2") as bar:
                state = predictor.init_state(video_path=tmp)
                predictor.add_new_points_or_box(inference_state=state, frame_idx=0, obj_id=1, points=points,
                                                labels=labels)
                for frame_idx, obj_ids, mask_logits in predictor.propagate_in_video(state):
                    k = int(frame_idx)
                    if not 0 <= k < len(order):
                        raise PluginError(f"SAM2 returned frame {k} of a {len(order)}-frame video")
                    logits = torch.as_tensor(mask_logits).detach().float().cpu()
                    ids = list(obj_ids)
                    if 1 not in ids or logits.ndim != 4 or tuple(logits.shape[-2:]) != (H, W):
                        raise PluginError(f"SAM2 returned masks of shape {list(logits.shape)} for objects {ids}; "
                                          f"expected [objects, 1, {H}, {W}] including object 1")
                    out[order[k]] = (logits[ids.index(1), 0] > 0).numpy()
                    seen.add(k)
                    bar.update(1)
        if len(seen) != len(order):
            raise PluginError(f"SAM2 propagated {len(seen)} of {len(order)} frames")
        return ViewMasks(torch.from_numpy(out), dataset.names, "binary", 2, source=f"sam2 from {dataset.names[v0]}",
                         info={"frame_order": [dataset.names[v] for v in order]})
