"""SAM2 segmenter plumbing with the model call replaced (sam2 is not installed on the development machines)."""

from pathlib import Path

import numpy as np
import pytest
import torch

from roodi_sam2 import SAM2Segmenter, frame_order
from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.io.dataset import Dataset
from roodi_toolkit.errors import ConfigError, PluginError
from roodi_toolkit.pipeline.segment import Click, SegmentPrompt


def small_dataset(n=5, size=12):
    K = intrinsics_from_fov(0.8, size, size)
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)[[0, 3, 1, 4, 2]]  # shuffled around the circle
    cams = [Camera(look_at((4 * np.cos(a), 4 * np.sin(a), 1.0), (0, 0, 0)), K, size, size, name=f"r_{i:03d}")
            for i, a in enumerate(angles)]
    # one flat grey per view (JPEG keeps it), so a frame tells which view it was written from
    images = torch.linspace(0.1, 0.9, n)[:, None, None, None].expand(n, size, size, 3).contiguous()
    return Dataset(images=images, cameras=cams, splits=["train"] * n, background=(1.0, 1.0, 1.0),
                   bounds=np.array([[-1, -1, -1], [1, 1, 1.0]]))


class FakePredictor:
    """Records the calls; frame k's mask is a k+1-pixel-wide bar, so the frame -> view mapping can be checked."""

    def __init__(self, size):
        self.size = size
        self.calls = []

    def init_state(self, video_path):
        frames = sorted(Path(video_path).iterdir())
        self.calls.append(("init_state", [f.name for f in frames]))
        self.frames = [np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(f)) for f in frames]
        return {"n": len(frames)}

    def add_new_points_or_box(self, inference_state, frame_idx, obj_id, points, labels):
        self.calls.append(("add", frame_idx, obj_id, points.tolist(), labels.tolist(), points.dtype, labels.dtype))
        return frame_idx, [obj_id], torch.zeros(1, 1, self.size, self.size)

    def propagate_in_video(self, state):
        for k in range(state["n"]):
            logits = torch.full((1, 1, self.size, self.size), -5.0)
            logits[0, 0, :, : k + 1] = 5.0
            yield k, [1], logits


def test_frame_order_is_a_nearest_neighbour_chain():
    ds = small_dataset()
    order = frame_order(ds.cameras, 2)
    assert order[0] == 2 and sorted(order) == list(range(5))
    centres = np.stack([c.center for c in ds.cameras])
    for a, b in zip(order, order[1:]):
        rest = [i for i in order[order.index(b):]]
        assert np.linalg.norm(centres[b] - centres[a]) <= min(np.linalg.norm(centres[i] - centres[a]) for i in rest)


def test_plumbing_with_a_fake_predictor(tmp_path):
    ds = small_dataset()
    ckpt = tmp_path / "sam2.pt"
    ckpt.write_bytes(b"not used by the fake")
    fake = FakePredictor(12)
    built = []

    def factory(config, checkpoint, device):
        built.append((config, checkpoint, device))
        return fake

    seg = SAM2Segmenter(checkpoint=str(ckpt), predictor_factory=factory)
    masks = seg.segment(ds, SegmentPrompt((Click("r_002", 3.5, 7.0), Click("r_002", 5.0, 6.0, positive=False))))
    assert built == [("configs/sam2.1/sam2.1_hiera_t.yaml", str(ckpt), "cpu")]
    assert fake.calls[0] == ("init_state", [f"{k:05d}.jpg" for k in range(5)])
    # frame 0 is the clicked view's image (JPEG, so close but not exact)
    order = frame_order(ds.cameras, 2)
    for k, v in enumerate(order):
        assert np.abs(fake.frames[k] / 255.0 - ds.images[v].numpy()).max() < 0.02
    _, frame, obj, points, labels, pdt, ldt = fake.calls[1]
    assert (frame, obj, points, labels) == (0, 1, [[3.5, 7.0], [5.0, 6.0]], [1, 0])  # SAM: 0 = a negative click
    assert pdt == np.float32 and ldt == np.int32
    assert masks.kind == "binary" and masks.num_classes == 2 and masks.names == ds.names
    for k, v in enumerate(order):
        assert masks.masks[v].sum() == 12 * (k + 1)  # the bar of frame k landed on view order[k]
    assert masks.info["frame_order"] == [ds.names[v] for v in order]


def test_errors(tmp_path):
    ds = small_dataset()
    with pytest.raises(ConfigError, match="checkpoint"):
        SAM2Segmenter(predictor_factory=lambda *a: None).segment(ds, SegmentPrompt((Click("r_000", 1, 1),)))
    with pytest.raises(ConfigError, match="not found"):
        SAM2Segmenter(checkpoint=str(tmp_path / "missing.pt")).segment(ds, SegmentPrompt((Click("r_000", 1, 1),)))
    ckpt = tmp_path / "c.pt"
    ckpt.write_bytes(b"x")
    with pytest.raises(ConfigError, match="same view"):
        SAM2Segmenter(checkpoint=str(ckpt)).segment(ds, SegmentPrompt((Click("r_000", 1, 1), Click("r_001", 1, 1))))

    class Wrong(FakePredictor):
        def propagate_in_video(self, state):
            yield 0, [1], torch.zeros(1, 1, 5, 5)

    with pytest.raises(PluginError, match="shape"):
        SAM2Segmenter(checkpoint=str(ckpt), predictor_factory=lambda *a: Wrong(12)).segment(
            ds, SegmentPrompt((Click("r_000", 1, 1),)))


def test_missing_sam2_is_reported_with_an_install_hint(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "sam2" else real(name, *a))
    ok, why = SAM2Segmenter.available()
    assert not ok and "pip install" in why
    from roodi_toolkit.pipeline.segment import get_segmenter

    with pytest.raises(PluginError, match="pip install"):
        get_segmenter("sam2")
