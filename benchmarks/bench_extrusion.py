"""The extrusion's copies alone: each target's selected object with its copies, before fine-tuning, against the truth.

Reads a finished ``bench_occluded.py`` run (``OUT/<scene>/full/object_<id>/selected.ply`` and the support recorded in
its ``debug/refine.json``) and renders the selected object with the copies that
:func:`roodi_toolkit.pipeline.support.extrude_to_support` makes under each rule set, from the target's object-alone
test views: the box PSNR of the paper's metric, per target and its mean. No mirror, no see-through test and no
fine-tuning, so it isolates what the copies themselves add; the full method's figures come from ``bench_occluded.py``.

Usage: .venv/bin/python benchmarks/bench_extrusion.py SCENES OUT [--variant repeated --variant all ...]

Variants: ``none`` (the selection alone), ``repeated`` (the band as it is: every colour, every size, kept while the
centre is above the support), ``clip`` (copies end at the support), ``clip+mean`` (and the band's mean colour),
``all`` (and sizes capped: the default).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VARIANTS = {"none": None, "repeated": dict(reach=0.0, mean_colour=False, cap_scales=False),
            "clip": dict(reach=2.0, mean_colour=False, cap_scales=False),
            "clip+mean": dict(reach=2.0, mean_colour=True, cap_scales=False),
            "all": dict(reach=2.0, mean_colour=True, cap_scales=True)}
UP = (0.0, 0.0, 1.0)  # the generated scenes' up axis: their objects stand on z = 0


def box_psnr(cloud, truth) -> float:
    """Mean over the test views of the PSNR in the 1.2x box around the true object (the paper's box metric)."""
    from roodi_toolkit.evaluate.metrics import box_around, psnr
    from roodi_toolkit.render.renderer import render_cloud

    values = []
    for i, cam in enumerate(truth.cameras):
        box = box_around(truth.alphas[i].numpy())
        if box is None:
            continue
        y0, y1, x0, x1 = box
        rgb = render_cloud(cloud, cam, background=(1.0, 1.0, 1.0)).rgb.clamp(0, 1).numpy()
        values.append(psnr(rgb[y0:y1, x0:x1], truth.images[i].numpy()[y0:y1, x0:x1]))
    return float(np.mean(values))


def main(argv: list[str] | None = None) -> int:
    from roodi_toolkit.run.evaluate import find_target
    from roodi_toolkit.gaussians import GaussianCloud
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.generated import read_scene_record
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.pipeline.support import extrude_to_support

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", type=Path, help="the scenes' ROOT of bench_occluded.py")
    ap.add_argument("out", type=Path, help="its OUT")
    ap.add_argument("--variant", action="append", choices=tuple(VARIANTS), help="repeat; default all five")
    args = ap.parse_args(argv)
    variants = args.variant or list(VARIANTS)
    scores: dict[str, list[float]] = {v: [] for v in variants}
    for scene in sorted(p for p in args.out.iterdir() if (p / "full").is_dir()):
        data = args.scenes / scene.name
        for target in read_scene_record(data)["targets"]:
            folder = scene / "full" / f"object_{int(target['id'])}"
            if not (folder / "selected.ply").is_file():
                continue
            selected = read_ply(folder / "selected.ply")
            support = json.loads((folder / "debug" / "refine.json").read_text()).get("support")
            truth = load_dataset(find_target(data, int(target["id"]))[0], background=(1.0, 1.0, 1.0))
            row = f"{scene.name:<22} {target['name']:<10}"
            for v in variants:
                cloud = selected
                if VARIANTS[v] is not None and support is not None:
                    copies = extrude_to_support(selected, UP, support, **VARIANTS[v])
                    cloud = GaussianCloud.concatenate([selected, copies]) if len(copies) else selected
                scores[v].append(box_psnr(cloud, truth))
                row += f" {v} {scores[v][-1]:6.2f}"
            print(row, flush=True)
    print("mean box PSNR over", len(scores[variants[0]]), "targets:",
          ", ".join(f"{v} {np.mean(s):.2f} dB" for v, s in scores.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
