"""Real-scene safety of a prune against the photos (issue 19): held-out PSNR of a trained model before and after.

    roodi-toolkit prune models/statue/point_cloud/iteration_2000/point_cloud.ply /tmp/pruned.ply
    .venv/bin/python benchmarks/bench_prune_heldout.py models/statue /tmp/pruned.ply

Renders the model's held-out views (every ``holdout_every``-th, as training held them out; data folder and downscale
from the model's ``cfg.json``) on the dataset's background from both clouds and prints the mean PSNR against the
photos. The issue's check: the pruned cloud no worse than the unpruned one, within 0.1 dB.
"""

from __future__ import annotations

import sys

import numpy as np


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__)
        return 2
    import torch

    from roodi_toolkit.imaging import psnr
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.model import find_model
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.io.dataset import split_views
    from roodi_toolkit.render.renderer import render_cloud

    torch.set_num_threads(1)
    model = find_model(argv[0])
    cfg = model.config
    ds = load_dataset(cfg["data_dir"], float(cfg.get("downscale", 1) or 1))
    _, held_out = split_views(ds, int(cfg.get("holdout_every", 8)))
    figures = {}
    for name, cloud in (("unpruned", read_ply(model.ply_path)), ("pruned", read_ply(argv[1]))):
        values = [psnr(render_cloud(cloud, ds.cameras[i], background=ds.background).rgb.clamp(0, 1).numpy(),
                       ds.images[i].numpy()) for i in held_out]
        figures[name] = float(np.mean(values))
        print(f"{name}: {len(cloud):,} Gaussians, held-out PSNR {figures[name]:.2f} dB ({len(held_out)} views)")
    print(f"pruned - unpruned: {figures['pruned'] - figures['unpruned']:+.2f} dB (goal: >= -0.1 dB)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
