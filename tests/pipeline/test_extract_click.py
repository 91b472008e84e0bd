"""extract on any trained model: data folder and resolution from its cfg.json, the object chosen by a click given in
the original photo's pixels and grown through the scene into every view."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from roodi_toolkit import read_ply
from roodi_toolkit.io.dataset import load_dataset


@pytest.fixture(scope="module")
def half_model(tmp_path_factory):
    """64x64 photos of two objects and a model of them recorded, as ``train --downscale 2`` records it, as trained
    at 32x32 (the ground-truth cloud stands in for training, which these tests are not about)."""
    from roodi_toolkit.io.files import write_json

    from ..object_scene import write_object_scene

    data, model, _ = write_object_scene(tmp_path_factory.mktemp("scene"), size=64)
    write_json({"data_dir": str(data), "downscale": 2.0, "iterations": 7, "holdout_every": 8}, model / "cfg.json")
    return data, model


def _object_pixel(data, view, obj):
    """A pixel near the middle of object ``obj`` in ``view``'s full-size mask (the photo's own pixels)."""
    ds = load_dataset(data)
    i = ds.names.index(view)
    ys, xs = np.nonzero((ds.masks[i] == obj).numpy())
    k = int(np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2))
    return int(xs[k]), int(ys[k])


def test_extract_by_click_on_a_downscaled_model(half_model, tmp_path, run_cli):
    data, model = half_model
    view = "r_003"
    x, y = _object_pixel(data, view, 2)
    out = tmp_path / "o"
    res = run_cli("extract", out, "--model", model, "--click", f"{x},{y}", "--view", f"{view}.png", "--no-inpaint",
                  "--distill-iterations", "20", "-q")
    assert res.exit_code == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["downscale"] == 2.0 and report["data_dir"] == str(data)
    assert len(read_ply(out / "object_1" / "object.ply")) > 0
    distill = json.loads((out / "distill" / "distill.json").read_text())
    assert distill["segmenter"] == "click"
    # recorded as given, in photo pixels
    assert distill["prompt"]["clicks"] == [{"view": view, "x": x, "y": y, "positive": True}]
    # the distilled masks are at the training size and hold the clicked object in the clicked view
    from roodi_toolkit.io.files import read_image

    mask = read_image(out / "distill" / "object_masks" / f"{view}.png")
    assert mask.shape == (32, 32) and mask[y // 2, x // 2] == 1
    # and match the object's own masks at that size well
    from roodi_toolkit.imaging import mask_iou

    half = load_dataset(data, 2)
    assert mask_iou(torch.from_numpy(mask == 1), half.masks[half.names.index(view)] == 2) > 0.7
    # the same selection again reuses every stage; another click distils again
    again = run_cli("extract", out, "--model", model, "--click", f"{x},{y}", "--view", view, "--no-inpaint",
                    "--distill-iterations", "20", "-q")
    assert again.exit_code == 0 and "reused finished stages: distill, object 1" in again.stdout


def test_extract_click_errors_write_nothing(half_model, tmp_path, run_cli):
    data, half_model = half_model
    out = tmp_path / "o"
    # 40,5 is inside the 32x32 loaded image, but these are the 64x64 photo's pixels: 70,5 is outside
    res = run_cli("extract", out, "--model", half_model, "--click", "70,5", "-q")
    assert res.exit_code == 1 and "click 70,5 is outside the 64x64 image r_000" in res.stderr
    assert not out.exists()
    res = run_cli("extract", out, "--model", half_model, "--click", "4,5", "--view", "nope", "-q")
    assert res.exit_code == 1 and "no view named 'nope'" in res.stderr and not out.exists()
    res = run_cli("extract", out, "--model", half_model, "-q")
    assert res.exit_code == 2 and "--object ID" in res.stderr and "--click" in res.stderr
    res = run_cli("extract", out, "--view", "r_000", "--model", half_model, "-q")
    assert res.exit_code == 2 and "--click" in res.stderr
    res = run_cli("extract", out, "--click", "4,5", "-q")
    assert res.exit_code == 2 and "--model" in res.stderr
    res = run_cli("extract", out, "--model", half_model, "--click", "4,5", "--segmenter", "files", "-q")
    assert res.exit_code == 2 and "takes no --click" in res.stderr
    res = run_cli("extract", out, "--model", half_model, "--click", "1,1", "--view", "r_003", "-q")
    assert res.exit_code == 1 and "hits no surface" in res.stderr  # the white background
    assert not out.exists()


def test_distill_takes_clicks_in_photo_pixels_too(half_model, tmp_path, run_cli):
    """distill, like extract, reads --click in the photo's own pixels whatever the model's downscale."""
    from roodi_toolkit.io.files import read_image

    data, model = half_model
    view = "r_003"
    x, y = _object_pixel(data, view, 2)
    out = tmp_path / "d"
    res = run_cli("distill", model, data, out, "--segmenter", "click", "--click", f"{view}:{x},{y}",
                  "--iterations", "5", "-q")
    assert res.exit_code == 0, res.stderr
    mask = read_image(out / "object_masks" / f"{view}.png")
    assert mask.shape == (32, 32) and mask[y // 2, x // 2] == 1
    res = run_cli("distill", model, data, tmp_path / "e", "--segmenter", "click", "--click", f"{view}:70,5", "-q")
    assert res.exit_code == 1 and "click 70,5 is outside the 64x64 image r_003" in res.stderr
    assert not (tmp_path / "e").exists()


def test_extract_negative_click(half_model, tmp_path, run_cli):
    data, model = half_model
    view = "r_003"
    x, y = _object_pixel(data, view, 2)
    nx, ny = _object_pixel(data, view, 1)
    out = tmp_path / "o"
    res = run_cli("extract", out, "--model", model, "--click", f"{x},{y}", "--negative-click", f"{nx},{ny}",
                  "--view", view, "--no-inpaint", "--distill-iterations", "5", "-q")
    assert res.exit_code == 0, res.stderr
    from roodi_toolkit.io.files import read_image

    distill = json.loads((out / "distill" / "distill.json").read_text())
    assert distill["prompt"]["clicks"] == [{"view": view, "x": x, "y": y, "positive": True},
                                           {"view": view, "x": nx, "y": ny, "positive": False}]
    mask = read_image(out / "distill" / "object_masks" / f"{view}.png")
    assert mask[y // 2, x // 2] == 1 and mask[ny // 2, nx // 2] == 0
    res = run_cli("extract", tmp_path / "n", "--model", model, "--negative-click", f"{nx},{ny}", "-q")
    assert res.exit_code == 2 and "--click" in res.stderr and not (tmp_path / "n").exists()


def test_extract_segmenter_options_are_checked_before_any_work(half_model, tmp_path, run_cli):
    data, model = half_model
    out = tmp_path / "o"
    res = run_cli("extract", out, "--model", model, "--click", "4,5", "--segmenter-option", "oops", "-q")
    assert res.exit_code == 2 and "expected KEY=VALUE, got 'oops'" in res.stderr and not out.exists()
