"""notebooks/walkthrough.ipynb: committed clean, and every cell runs top to bottom (sizes shrunk for speed).

The cells are executed with ``exec`` in one namespace, as a kernel would run them, so the test needs no Jupyter
kernel. The parameter cell (tagged ``parameters``, as papermill expects) runs first; :data:`FAST` then replaces its
sizes.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "walkthrough.ipynb"

FAST = {
    "N_OBJECT": 3000, "WINDOW_SIZE": (320, 240), "ORBIT_VIEWS": 2, "RENDER_SIZE": 64,
    "SCENE_SIZE": 32, "TRAIN_VIEWS": 10, "TEST_VIEWS": 2, "TRAIN_ITERATIONS": 40, "INIT_POINTS": 800,
    "CAP_MAX": 1000, "DISTILL_ITERATIONS": 40, "OCCLUSION_SIZE": 32, "FINETUNE_ITERATIONS": 4,
}
"""Sizes known to run fast (tests/conftest.py's ``tiny_kitchen``, tests/pipeline/test_extract.py)."""


def _cells() -> list[dict]:
    return json.loads(NOTEBOOK.read_text(encoding="utf-8"))["cells"]


def _source(cell: dict) -> str:
    return "".join(cell["source"])


def test_notebook_is_valid_and_committed_without_outputs():
    nb = json.loads(NOTEBOOK.read_text(encoding="utf-8"))
    assert nb["nbformat"] == 4 and nb["nbformat_minor"] >= 5
    assert nb["metadata"]["kernelspec"]["name"] == "python3"
    ids = [cell["id"] for cell in nb["cells"]]
    assert len(set(ids)) == len(ids)
    for cell in nb["cells"]:
        assert cell["cell_type"] in ("markdown", "code") and isinstance(cell["source"], list)
        if cell["cell_type"] == "code":
            assert cell["outputs"] == [] and cell["execution_count"] is None, f"clear the outputs of {cell['id']}"
    params = [c for c in nb["cells"] if "parameters" in c["metadata"].get("tags", [])]
    assert len(params) == 1 and params[0]["cell_type"] == "code"
    defined: dict = {}
    exec(_source(params[0]), defined)
    assert set(FAST) <= set(defined), "FAST overrides a parameter the notebook no longer has"
    assert NOTEBOOK.stat().st_size < 64_000
    try:
        import nbformat
    except ImportError:
        return
    nbformat.validate(nbformat.reads(NOTEBOOK.read_text(encoding="utf-8"), as_version=4))


def test_walkthrough_runs_top_to_bottom(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pyvista as pv

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PYVISTA_OFF_SCREEN", "true")
    # the notebook sets these globals; put them back for the tests that run after this one
    monkeypatch.setattr(pv, "OFF_SCREEN", pv.OFF_SCREEN)
    monkeypatch.setenv("ROODI_PLUGINS", "")
    monkeypatch.setattr(sys, "path", list(sys.path))

    namespace: dict = {"__name__": "__main__"}
    ran = []
    try:
        for cell in _cells():
            if cell["cell_type"] != "code":
                continue
            # the file name puts the cell's id into any traceback
            exec(compile(_source(cell), f"walkthrough.ipynb[{cell['id']}]", "exec"), namespace)
            if "parameters" in cell["metadata"].get("tags", []):
                namespace.update(FAST)
            ran.append(cell["id"])
    finally:
        plt.close("all")
        sys.modules.pop("walkthrough_mean_inpainter", None)  # the toy plugin module the notebook writes

    assert ran == [c["id"] for c in _cells() if c["cell_type"] == "code"]
    out = tmp_path / namespace["OUT_DIR"]
    object_id = namespace["object_id"]
    for name in ("with_floaters.ply", "pruned.ply", "floaters.ply", "floaters.png", "pruned_orbit.png",
                 f"extract/object_{object_id}/object.ply", f"extract_mean/object_{object_id}/object.ply",
                 "evaluation.png", "inpainting_grids.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name

    from roodi_toolkit import read_ply

    assert len(read_ply(out / "pruned.ply")) == int(namespace["keep"].sum()) < len(read_ply(out / "with_floaters.ply"))
    assert len(read_ply(out / f"extract/object_{object_id}/object.ply")) > 0
    assert 0 <= namespace["evaluation"].iou <= 1 and len(namespace["evaluation"].views) == FAST["TEST_VIEWS"]
    assert namespace["mean_entry"]["inpainter"] == "mean"
    assert Path(namespace["mean_extraction"]["distill_dir"]).parts[-2:] == ("extract", "distill")
