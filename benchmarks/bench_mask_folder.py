"""Reading a folder of mask PNGs for the files segmenter: peak memory (tracemalloc, numpy's allocations) and time,
at full size (``select``'s picture, ``extract``'s inpainting masks) and at distillation's working size (1/2 for 800
px views under its 512x512 budget).

    .venv/bin/python benchmarks/bench_mask_folder.py [--views 120] [--size 800]

Runs on any tree: with ``roodi_toolkit/run/masks.py`` the run layer reads the folder (``io/masks.py``) and hands
the masks to the segmenter in memory; without it (before issue 35's step) the segmenter reads the folder itself.
The masks (a 300 px square each, 0/255) are written under a temporary folder first.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from roodi_toolkit.io.files import write_image  # noqa: E402
from roodi_toolkit.pipeline.segment import FilesSegmenter, SegmentPrompt  # noqa: E402

RUN_LAYER = importlib.util.find_spec("roodi_toolkit.run.masks") is not None


def read(folder: Path, full: SimpleNamespace, ds: SimpleNamespace):
    """Return the ViewMasks of ``ds``'s views (``full``, or its working size) from ``folder``."""
    if not RUN_LAYER:
        return FilesSegmenter(folder).segment(ds, SegmentPrompt())
    from roodi_toolkit.run.masks import folder_masks, options_with_masks

    if ds is full:
        return folder_masks(folder, full)
    options = options_with_masks("files", None, SegmentPrompt(mask_dir=folder), full, max_pixels=512 * 512)
    return FilesSegmenter(**options).segment(ds, SegmentPrompt(mask_dir=folder))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=120)
    ap.add_argument("--size", type=int, default=800)
    args = ap.parse_args()
    n, s = args.views, args.size
    names = [f"r_{i:03d}" for i in range(n)]
    full = SimpleNamespace(names=names, width=s, height=s, masks=None)
    work = SimpleNamespace(names=names, width=s // 2, height=s // 2, masks=None)
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "masks"
        folder.mkdir()
        for name in names:
            m = np.zeros((s, s), np.uint8)
            y, x = rng.integers(0, s - 300, 2)
            m[y:y + 300, x:x + 300] = 255
            write_image(m, folder / f"{name}.png")
        for label, ds in (("full size", full), ("working size 1/2", work)):
            read(folder, full, ds)  # warm: imports, first reads
            tracemalloc.start()
            t = time.perf_counter()
            masks = read(folder, full, ds)
            seconds = time.perf_counter() - t
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            print(f"{'run layer' if RUN_LAYER else 'segmenter reads'}: {label}: {n} masks of {s} px -> "
                  f"{list(masks.masks.shape)} {masks.masks.dtype}, peak {peak / 2**20:.0f} MiB, {seconds:.2f} s")


if __name__ == "__main__":
    main()
