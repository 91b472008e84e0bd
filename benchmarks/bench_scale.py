"""Benchmark: extraction at the size people bring, stage by stage: time and peak memory, and the object's accuracy.

``run SCENE`` takes a capture built by ``benchmarks/scale_scene.py`` (photos rendered from a real splat, the splat as
the trained model, the object's true Gaussians) and runs the extraction the way a user does
(``extract DATA OUT --model MODEL --click X,Y --view NAME``, in this process, default settings), timing each stage
and sampling the process's resident memory every 20 ms, then scores the object against the truth on the held-out
cameras (alpha > 0.5 IoU of the object alone, before inpainting and fine-tuning (``selected.ply``) and after). The
click is the visible pixel of the object nearest its centre in the view, or ``--click``.

``grid`` builds the scenes of a sweep (``--gaussians`` in thousands: copies of the splat side by side, or a random
subset of it below its size; ``--views``; ``--size``) and runs each, printing one table: how each stage's time and
memory grow with Gaussians N, photos V and pixels P. Scenes are built under ``--work`` and reused.

Run:
    .venv/bin/python benchmarks/bench_scale.py run /tmp/scale/p500 --view r_10
    .venv/bin/python benchmarks/bench_scale.py grid /tmp/splats/playbot0/meta.json --work /tmp/scale \\
        --gaussians 150,500,1500 --views 30 --size 800
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


class MemorySampler:
    """Samples the resident set size of this process in a thread; ``window()`` gives the peak of a span."""

    def __init__(self, every: float = 0.02) -> None:
        self.every = every
        self.current = self.peak_all = self._rss()
        self.peak_time = time.perf_counter()
        self.spans: list[tuple[str, float, float]] = []  # (stage, start, end), in perf_counter seconds
        self._peak = self.current
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @staticmethod
    def _rss() -> float:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

    def _run(self) -> None:
        while not self._stop.is_set():
            self.current = self._rss()
            self._peak = max(self._peak, self.current)
            if self.current > self.peak_all:
                self.peak_all, self.peak_time = self.current, time.perf_counter()
            time.sleep(self.every)

    @contextmanager
    def window(self, record: dict, name: str):
        outer = self._peak
        self._peak = self.current
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.spans.append((name, t0, time.perf_counter()))
            entry = record.setdefault(name, {"s": 0.0, "peak_mb": 0.0})
            entry["s"] += time.perf_counter() - t0
            entry["peak_mb"] = max(entry["peak_mb"], self._peak)
            self._peak = max(outer, self._peak)

    def stop(self) -> None:
        self._stop.set()

    def peak_stage(self) -> str:
        """Name where the process's peak fell: the innermost stage holding it, else the stages it fell between."""
        at = self.peak_time
        inner = [(e - b, n) for n, b, e in self.spans if n != "total" and b <= at <= e]
        if inner:
            return min(inner)[1]
        before = [n for n, b, e in sorted(self.spans, key=lambda x: x[2]) if e < at and n != "total"]
        after = [n for n, b, e in sorted(self.spans, key=lambda x: x[1]) if b > at and n != "total"]
        return f"between {before[-1] if before else 'start'} and {after[0] if after else 'end'}"


STAGES = [  # (module defining it, class or "", function, stage name): what the extraction calls
    ("roodi_toolkit.io.dataset", "", "load_dataset", "load photos"),
    ("roodi_toolkit.io.ply", "", "read_ply", "read model"),
    ("roodi_toolkit.pipeline.resolution", "", "working_dataset", "working size"),
    ("roodi_toolkit.pipeline.click", "ClickSegmenter", "segment", "click segment"),
    ("roodi_toolkit.pipeline.distill", "", "distill_object_features", "distill"),
    ("roodi_toolkit.pipeline.distill", "", "finish_distillation", "score distillation"),
    ("roodi_toolkit.run.distill", "", "save_distilled", "save distillation"),
    ("roodi_toolkit.pipeline.select", "", "select_object", "select"),
    ("roodi_toolkit.pipeline.select", "", "prune_selection", "prune"),
    ("roodi_toolkit.pipeline.finetune", "", "refine_object", "occlusion+inpaint+fine-tune"),
]


def instrument(sampler: MemorySampler, record: dict) -> None:
    """Wrap each stage's function in a timing window, under every name the package's loaded modules know it by
    (modules import their callees' names at their top, so the defining module's attribute alone is not enough)."""
    import importlib

    importlib.import_module("roodi_toolkit.run.extract")  # the whole chain, so every caller is loaded
    modules = [m for name, m in list(sys.modules.items()) if name.startswith("roodi_toolkit") and m is not None]
    for module, cls, attr, name in STAGES:
        owner = importlib.import_module(module)
        owner = getattr(owner, cls) if cls else owner
        original = getattr(owner, attr)

        def wrapped(*a, __f=original, __n=name, **k):
            with sampler.window(record, __n):
                return __f(*a, **k)

        if cls:
            setattr(owner, attr, wrapped)
            continue
        for m in modules:
            if getattr(m, attr, None) is original:
                setattr(m, attr, wrapped)


def default_click(scene: Path, view: str) -> tuple[int, int]:
    """Return the visible pixel of the true object nearest its centre in ``view``."""
    from roodi_toolkit.io.dataset import load_cameras
    from roodi_toolkit.io.model import find_model
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.render import fast

    truth = np.load(scene / "truth.npz")["object"]
    cloud = read_ply(find_model(scene / "model").ply_path)
    cam = next(c for c in load_cameras(scene / "data") if c.name == view)
    f = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    top, alpha, _ = fast.surface_ids(f(cloud.means), f(cloud.quats_wxyz), f(cloud.log_scales),
                                     f(cloud.opacity_logits),
                                     fast.make_view(cam.world_to_camera, cam.K, cam.width, cam.height))
    on = (top >= 0) & truth[np.maximum(top, 0)] & (alpha > 0.9)
    ys, xs = np.nonzero(on)
    k = int(np.argmin((xs - xs.mean()) ** 2 + (ys - ys.mean()) ** 2))
    return int(xs[k]), int(ys[k])


def object_scores(cloud, truth_cloud, cameras) -> tuple[float, float]:
    """Return the means over ``cameras`` of the IoU of alpha > 0.5 of ``cloud`` and of ``truth_cloud``, and of the
    PSNR (dB) of their colours on black."""
    from roodi_toolkit.imaging import mask_iou
    from roodi_toolkit.render.renderer import render_cloud

    ious, psnrs = [], []
    for cam in cameras:
        a, b = render_cloud(cloud, cam), render_cloud(truth_cloud, cam)
        ious.append(mask_iou(a.alpha[..., 0].numpy() > 0.5, b.alpha[..., 0].numpy() > 0.5))
        mse = float(((a.rgb - b.rgb) ** 2).mean())
        psnrs.append(10.0 * np.log10(1.0 / max(mse, 1e-12)))
    return float(np.mean(ious)), float(np.mean(psnrs))


def run(scene: Path, view: str, click: tuple[int, int] | None, out: Path, renderer: str | None = None,
        max_pixels: int | None = None, vote_views: int | None = None, distill_views: int | None = None) -> dict:
    """Run the extraction on one built scene (with the registered ``renderer``, default the built-in one); return
    times, peaks and IoUs. The IoUs are scored with the built-in renderer whatever ``renderer`` is. ``max_pixels``
    and ``vote_views`` change the working size of segmentation and distillation and the click's number of voting
    views (the defaults: 512x512 and 32), and ``distill_views`` the training views distillation learns from (default
    32, 0: all), to measure what the defaults lose against full size and all views."""
    sys.path.insert(0, str(ROOT))
    from roodi_toolkit.io.dataset import load_cameras
    from roodi_toolkit.io.model import find_model
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.pipeline.distill import DistillConfig
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.run.extract import extract_objects
    from roodi_toolkit.pipeline.segment import Click, SegmentPrompt

    sampler = MemorySampler()
    baseline = sampler.current
    record: dict = {}
    x, y = click if click is not None else default_click(scene, view)
    instrument(sampler, record)
    config = ExtractConfig(segmenter="click", prompt=SegmentPrompt((Click(view, x + 0.5, y + 0.5),)),
                           distill=DistillConfig(**{k: v for k, v in (("max_pixels", max_pixels),
                                                                      ("max_views", distill_views)) if v is not None}),
                           segmenter_options={} if vote_views is None else {"vote_views": vote_views})
    t0 = time.perf_counter()
    with sampler.window(record, "total"):
        extract_objects(scene / "data", out, [1], model_dir=scene / "model", config=config, overwrite=True,
                        renderer=renderer)
    total = time.perf_counter() - t0
    sampler.stop()
    truth = np.load(scene / "truth.npz")["object"]
    model = read_ply(find_model(scene / "model").ply_path)
    test = load_cameras(scene / "data", splits=["test"])
    result = {"scene": str(scene), "renderer": renderer or "numba", "gaussians": len(model), "click": [view, x, y], "seconds": total,
              "peak_mb": sampler.peak_all, "peak_at": sampler.peak_stage(), "baseline_mb": baseline,
              "stages": {k: {"s": round(v["s"], 1), "peak_mb": round(v["peak_mb"])} for k, v in record.items()}}
    result["iou_selected"], result["psnr_selected"] = object_scores(read_ply(out / "object_1" / "selected.ply"),
                                                                    model.select(truth), test)
    result["iou_object"], result["psnr_object"] = object_scores(read_ply(out / "object_1" / "object.ply"),
                                                                model.select(truth), test)
    report = json.loads((out / "report.json").read_text())
    result["views"] = len(load_cameras(scene / "data", splits=["train"]))
    result["size"] = [test[0].width, test[0].height]
    result["working"] = report.get("distill", {}).get("working_size")
    return result


def grid(args) -> None:
    rows = []
    for n in [int(v) for v in args.gaussians.split(",")]:
        for v in [int(x) for x in args.views.split(",")]:
            for size in [int(x) for x in args.size.split(",")]:
                scene = args.work / f"n{n}k_v{v}_s{size}"
                if not (scene / "truth.npz").is_file():
                    cmd = [sys.executable, str(HERE / "scale_scene.py"), args.splat, str(scene), "--views", str(v),
                           "--size", str(size), "--gaussians", str(n * 1000)]
                    subprocess.run(cmd, check=True)
                cmd = [sys.executable, __file__, "run", str(scene), "--view", "r_1", "--json"]
                res = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
                rows.append(res)
                print(json.dumps(res), flush=True)
    print(table(rows))


def table(rows: list[dict]) -> str:
    stages = [s for *_, s in STAGES]
    head = ["N", "V", "px", "total s", "peak MB"] + [f"{s} s/MB" for s in stages] + ["IoU sel", "IoU obj"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in rows:
        cells = [f"{r['gaussians']:,}", str(r["views"]), "x".join(map(str, r.get("size", []))) or "",
                 f"{r['seconds']:.0f}", f"{r['peak_mb']:.0f}"]
        cells += [f"{r['stages'][s]['s']:.0f} / {r['stages'][s]['peak_mb']:.0f}" if s in r["stages"] else "-"
                  for s in stages]
        cells += [f"{r['iou_selected']:.3f}", f"{r['iou_object']:.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("scene", type=Path)
    r.add_argument("--view", default="r_10")
    r.add_argument("--click", default=None, help="X,Y in the view's pixels (default: the object's centre)")
    r.add_argument("--out", type=Path, default=None)
    r.add_argument("--json", action="store_true")
    r.add_argument("--renderer", default=None, help="a registered renderer (default the built-in one; gsplat on a GPU)")
    r.add_argument("--max-pixels", type=int, default=None, help="working size of segmentation and distillation "
                   "(default 512x512 = 262144; the photos' own size: full resolution)")
    r.add_argument("--vote-views", type=int, default=None, help="the click's voting views (default 32)")
    r.add_argument("--distill-views", type=int, default=None,
                   help="the training views distillation learns from (default 32 spread round the scene; 0: all)")
    r.add_argument("--no-support", action="store_true",
                   help="the click without the support plane of its clicked region (as before it)")
    g = sub.add_parser("grid")
    g.add_argument("splat")
    g.add_argument("--work", type=Path, default=Path("/tmp/scale"))
    g.add_argument("--gaussians", default="150,500,1500", help="thousands of Gaussians")
    g.add_argument("--views", default="30")
    g.add_argument("--size", default="800")
    args = ap.parse_args()
    if args.cmd == "run":
        if args.no_support:
            from roodi_toolkit.pipeline import click as click_module

            click_module.off_support = lambda cam0, depth0, region, *a, **k: (region, np.zeros_like(region))
        click = tuple(int(v) for v in args.click.split(",")) if args.click else None
        out = args.out or args.scene / "out"
        res = run(args.scene, args.view, click, out, renderer=args.renderer, max_pixels=args.max_pixels,
                  vote_views=args.vote_views, distill_views=args.distill_views)
        print(json.dumps(res) if args.json else json.dumps(res, indent=1))
    else:
        grid(args)


if __name__ == "__main__":
    main()
