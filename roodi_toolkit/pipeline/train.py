"""Train a 3DGS model of a whole scene on the CPU: L1 + D-SSIM with the MCMC densification strategy (paper, Sec. 3.1).

The loop follows the reference 3DGS / gsplat trainer: one Adam per parameter with the 3DGS learning rates (position
learning rate scaled by the scene extent and decayed exponentially by 100x over the run), loss
``(1 - 0.2) L1 + 0.2 (1 - SSIM)`` with an 11x11 window, SH degree raised every 1000 iterations, and the MCMC
strategy's regularisers, relocation, growth and position noise (:mod:`roodi_toolkit.pipeline.strategy`).

Everything random draws from one seeded ``torch.Generator`` whose state is checkpointed, so a run killed at any
moment and resumed from its last checkpoint continues exactly as the uninterrupted run would have.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict, dataclass, replace
from typing import Any, Callable

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from ..cameras import Camera
from ..io.dataset import Dataset, split_views  # split_views: importable from here as before
from .budget import check_train
from .init_points import depth_points, projected_colors, rgb_to_sh0, sfm_initial_points
from ..errors import DatasetError, InputError
from ..settings import check_settings, documented, setting
from ..gaussians import GaussianCloud
from ..imaging import psnr, ssim as ssim_value
from ..progress import ProgressFactory, null_progress
from ..params import GaussianParams
from ..render.renderer import Renderer, RenderOutput, resolve_renderer
from .strategy import MCMCStrategy, MCMCState
from .train_kernels import ssim as ssim_loss

CHECKPOINT_VERSION = 2
"""Version 2: parameters under GaussianParams' names (``log_scales``, ``opacity_logits``, ``sh_dc [N, 3]``)."""


@documented
@dataclass(frozen=True)
class TrainConfig:
    """Hyperparameters of scene training. Sources: 3DGS (learning rates, loss), gsplat/3DGS-MCMC (init, MCMC)."""

    iterations: int = setting(3000, "Optimisation steps, one view each.", low=1)
    # 3DGS: 3, reached by raising it every sh_degree_interval steps
    sh_degree: int = setting(3, "Largest SH degree.", low=0, high=3)
    sh_degree_interval: int = setting(1000, "Raise the SH degree every this many steps.", low=1, cli=False)
    # 3DGS: 0.2 and an 11 px window
    ssim_lambda: float = setting(0.2, "Weight of D-SSIM in the loss.", low=0, high=1, cli=False)
    ssim_window: int = setting(11, "SSIM window in pixels.", low=1, cli=False)
    # 3DGS: 1.6e-4, decayed to means_lr * means_lr_final at the last step; the other rates are 3DGS's too
    means_lr: float = setting(1.6e-4, "Position learning rate per unit of scene scale.", low=0, cli=False)
    means_lr_final: float = setting(0.01, "Final position learning rate, a fraction of means_lr.", low=0, cli=False)
    scales_lr: float = setting(5e-3, "Learning rate of the log scales.", low=0, cli=False)
    quats_lr: float = setting(1e-3, "Learning rate of the rotations.", low=0, cli=False)
    opacities_lr: float = setting(5e-2, "Learning rate of the opacity logits.", low=0, cli=False)
    sh0_lr: float = setting(2.5e-3, "Learning rate of the base colours.", low=0, cli=False)
    shN_lr: float = setting(2.5e-3 / 20, "Learning rate of the higher SH coefficients.", low=0, cli=False)
    init: str = setting("auto", "Initial Gaussians: sparse points (COLMAP), random in the scene box, or lifted from "
                        "the views' depth maps (datasets with depth, e.g. make-scene); auto: the points if any, else "
                        "random.", choices=("auto", "points", "random", "depth"))
    # ours: sized for the CPU (gsplat uses 100,000); sfm_initial_points tops sparse points up
    init_num_points: int = setting(20_000, "Random initialisation size; sparse SfM points fewer than this are topped "
                                   "up to it.", low=4, option="--init-points")
    # 3DGS-MCMC: 0.5 and 0.1
    init_opacity: float = setting(0.5, "Initial opacity.", low=0, high=1, low_open=True, high_open=True, cli=False)
    init_scale: float = setting(0.1, "Initial scale, a fraction of the mean distance to the 3 nearest points.",
                                low=0, low_open=True, cli=False)
    # a fixed colour grows floaters of that colour, visible on any other background; the Trainer resolves None to the
    # value used, which cfg.json and checkpoints record
    random_background: bool | None = setting(
        None, "Render on a random colour each step (images with alpha are composited on it; opaque photos then teach "
        "every pixel to be covered), or on the dataset's background [default: random when the images have alpha, as "
        "3DGS trainers do; cfg.json records the choice].", option="--random-background/--fixed-background")
    holdout_every: int = setting(8, "Without a test split, hold out every n-th training view (0: none).", low=0,
                                 cli=False)
    # NumPy's generators refuse negative seeds; NumPy's legacy seeding stops at 32 bits (the CLI's SEED_RANGE)
    seed: int = setting(0, "Random seed of every random choice.", low=0, high=2 ** 32 - 1)
    eval_every: int = setting(500, "Evaluate on the held-out views this often (0: only at the end).", low=0)
    checkpoint_every: int = setting(250, "Write a resumable checkpoint this often.", low=1)
    # cap_max sized for the CPU (3DGS-MCMC uses 1-3 million)
    strategy: MCMCStrategy = setting(factory=lambda: MCMCStrategy(cap_max=60_000),
                                     help="The MCMC densification's settings.", prefix="")

    def __post_init__(self) -> None:
        check_settings(self)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TrainConfig":
        d = dict(d)
        strategy = MCMCStrategy(**d.pop("strategy", {}))
        return cls(**d, strategy=strategy)


def scene_scale(cameras: list[Camera]) -> float:
    """Return 1.1 x the largest camera distance from the cameras' mean centre (3DGS ``cameras_extent``)."""
    centres = np.stack([c.center for c in cameras])
    return float(1.1 * np.linalg.norm(centres - centres.mean(axis=0), axis=1).max()) or 1.0


def initial_params(points: np.ndarray, colors: np.ndarray | None, config: TrainConfig,
                   generator: torch.Generator) -> GaussianParams:
    """Return the initial trainable Gaussians at ``points`` [P, 3] (3DGS-MCMC: scales from the 3 nearest neighbours)."""
    pts = torch.as_tensor(np.asarray(points), dtype=torch.float32)
    n = len(pts)
    if n < 4:
        raise DatasetError(f"need at least 4 initial points, got {n}")
    dist, _ = cKDTree(pts.numpy()).query(pts.numpy(), k=4)
    dist_avg = torch.as_tensor(np.sqrt((dist[:, 1:] ** 2).mean(axis=1)), dtype=torch.float32).clamp_min(1e-7)
    if colors is None:
        rgb = torch.rand(n, 3, generator=generator)
    else:
        rgb = torch.as_tensor(np.asarray(colors), dtype=torch.float32)
        rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
    k = (config.sh_degree + 1) ** 2
    params = GaussianParams(
        means=pts,
        quats_wxyz=torch.rand(n, 4, generator=generator),
        log_scales=torch.log(dist_avg * config.init_scale)[:, None].repeat(1, 3),
        opacity_logits=torch.full((n,), math.log(config.init_opacity / (1 - config.init_opacity))),
        sh_dc=rgb_to_sh0(rgb),
        sh_rest=torch.zeros(n, k - 1, 3),
    )
    return params.requires_grad_()


class Trainer:
    """Trains a scene model; holds the parameters, optimizers, strategy state and the random generator.

    Args:
        dataset: the posed images (train views are used for optimisation).
        config: hyperparameters.
        train_indices: views to optimise on (default: the dataset's train split minus held-out views).
        renderer: draws every training and evaluation view (default: the built-in CPU renderer).
    """

    def __init__(self, dataset: Dataset, config: TrainConfig = TrainConfig(),
                 train_indices: list[int] | None = None, *, renderer: Renderer | None = None) -> None:
        self.dataset = dataset
        self.renderer = resolve_renderer(renderer)
        if config.random_background is None:
            config = replace(config, random_background=dataset.alphas is not None)
        self.config = config
        self.train_indices, self.eval_indices = split_views(dataset, config.holdout_every)
        if train_indices is not None:
            self.train_indices = list(train_indices)
        if not self.train_indices:
            raise DatasetError("the dataset has no training views")
        largest = max(dataset.cameras, key=lambda cam: cam.width * cam.height)
        # the model grows to the densification's cap: refuse now what would not fit then, not hours into the run
        check_train(max(config.strategy.cap_max, config.init_num_points), largest.width, largest.height)
        self.generator = torch.Generator().manual_seed(config.seed)
        self.scale = scene_scale([dataset.cameras[i] for i in self.train_indices])
        self.strategy = config.strategy
        self.strategy_state = self.strategy.initialize_state()
        self.step = 0
        self._order: Tensor = torch.empty(0, dtype=torch.long)
        self._pos = 0
        self.history: list[dict[str, float]] = []
        self.params = initial_params(*self._initial_points(), config, self.generator)
        self._make_optimizers()

    # ------------------------------------------------------------------------------------------------ set-up
    def _initial_points(self) -> tuple[np.ndarray, np.ndarray | None]:
        ds, cfg = self.dataset, self.config
        if cfg.init == "depth":
            return depth_points(ds, self.train_indices, cfg.init_num_points, self.generator)
        use_points = cfg.init == "points" or (cfg.init == "auto" and ds.points is not None and len(ds.points) >= 4)
        if use_points:
            if ds.points is None or len(ds.points) < 4:
                raise DatasetError("init 'points' needs a dataset with sparse points (COLMAP)")
            return sfm_initial_points(ds, self.train_indices, cfg.init_num_points, self.generator)
        lo, hi = ds.bounds
        u = torch.rand(cfg.init_num_points, 3, generator=self.generator, dtype=torch.float64).numpy()
        points = lo + u * (hi - lo)
        return points, projected_colors(points, ds, self.train_indices)

    def _make_optimizers(self, fused: bool = True) -> None:
        cfg = self.config
        self.optimizers = self.params.adam(cfg, self.scale, fused=fused)
        gamma = cfg.means_lr_final ** (1.0 / max(cfg.iterations, 1))
        self.scheduler = torch.optim.lr_scheduler.ExponentialLR(self.optimizers["means"], gamma=gamma)

    @property
    def sh_degree(self) -> int:
        return min(self.step // self.config.sh_degree_interval, self.config.sh_degree)

    @property
    def num_gaussians(self) -> int:
        return len(self.params)

    def _next_view(self) -> int:
        if self._pos >= len(self._order):
            self._order = torch.randperm(len(self.train_indices), generator=self.generator)
            self._pos = 0
        view = self.train_indices[int(self._order[self._pos])]
        self._pos += 1
        return view

    # ------------------------------------------------------------------------------------------------ training
    def train_step(self) -> dict[str, float]:
        """Run one optimisation step on the next view; return its loss, PSNR and Gaussian count."""
        cfg = self.config
        view = self._next_view()
        camera = self.dataset.cameras[view]
        gt = self.dataset.images[view]
        background = torch.tensor(self.dataset.background, dtype=torch.float32)
        alpha = None if self.dataset.alphas is None else self.dataset.alphas[view][..., None]
        if cfg.random_background:
            old_background = background
            background = torch.rand(3, generator=self.generator)
            if alpha is not None:  # the images were composited on the dataset background: swap it for the new one
                gt = (gt + (1 - alpha) * (background - old_background)).clamp(0, 1)
        out = self.renderer.render(self.params, camera, sh_degree=self.sh_degree, background=background)
        rgb = out.rgb
        if self.dataset.valid is not None:  # masked pixels (nerfstudio's mask_path) count in neither image
            weight = self.dataset.valid[view][..., None]
            rgb, gt = rgb * weight, gt * weight
        l1 = torch.abs(rgb - gt).mean()
        ssim = ssim_loss(rgb, gt, cfg.ssim_window)  # kornia's SSIM, compiled with its backward
        loss = (1 - cfg.ssim_lambda) * l1 + cfg.ssim_lambda * (1 - ssim) + self.strategy.regularization(self.params)
        extra = self._extra_loss(out, view)
        if extra is not None:
            loss = loss + extra
        loss.backward()
        for opt in self.optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        means_lr = self.optimizers["means"].param_groups[0]["lr"]
        self.scheduler.step()
        self.strategy.step_post_backward(self.params, self.optimizers, self.strategy_state, self.step, means_lr,
                                         self.generator)
        self.step += 1
        return {"step": self.step, "loss": float(loss.detach()), "l1": float(l1.detach()),
                "psnr": psnr(rgb.detach().clamp(0, 1), gt), "count": self.num_gaussians}

    def _extra_loss(self, out: RenderOutput, view: int) -> Tensor | None:
        """Return a loss term added to the photometric loss of ``view`` (none here)."""
        return None

    @torch.no_grad()
    def evaluate(self, indices: list[int] | None = None) -> dict[str, float]:
        """Return mean PSNR and SSIM over ``indices`` (default: the held-out views)."""
        indices = self.eval_indices if indices is None else indices
        if not indices:
            return {}
        background = torch.tensor(self.dataset.background, dtype=torch.float32)
        psnrs, ssims = [], []
        colour_only = self.params.with_features(None)  # features (joint training) are not scored here
        for i in indices:
            out = self.renderer.render(colour_only, self.dataset.cameras[i], sh_degree=self.sh_degree,
                                       background=background)
            psnrs.append(psnr(out.rgb.clamp(0, 1), self.dataset.images[i]))
            ssims.append(float(ssim_value(out.rgb.clamp(0, 1), self.dataset.images[i])))
        return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims))}

    def to_cloud(self) -> GaussianCloud:
        """Return the current model as a GaussianCloud."""
        return self.params.to_cloud()

    # ------------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        """Return everything needed to resume: parameters, optimizers, scheduler, strategy, RNG and view order."""
        return {
            "version": CHECKPOINT_VERSION,
            "step": self.step,
            "config": self.config.to_dict(),
            "params": {k: v.detach().clone() for k, v in self.params.items()},
            "optimizers": {k: copy.deepcopy(opt.state_dict()) for k, opt in self.optimizers.items()},  # not views of live state
            "scheduler": self.scheduler.state_dict(),
            "strategy_state": self.strategy_state.state_dict(),
            "generator": self.generator.get_state(),
            "order": self._order.clone(),
            "pos": self._pos,
            "history": self.history,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a state from :meth:`state_dict` (the dataset and config must be the run's own)."""
        if state.get("version") != CHECKPOINT_VERSION:
            raise InputError(f"checkpoint version {state.get('version')} is not {CHECKPOINT_VERSION} (written by an "
                             "older roodi-toolkit, before the parameters were renamed); train afresh with --overwrite")
        try:
            self.params = GaussianParams(**{k: torch.nn.Parameter(state["params"][k].clone())
                                            for k in self.params.keys()})
            self._make_optimizers()
            for k, opt in self.optimizers.items():
                opt.load_state_dict(state["optimizers"][k])
            self.scheduler.load_state_dict(state["scheduler"])
            self.strategy_state = MCMCState()
            self.strategy_state.load_state_dict(state["strategy_state"])
            self.generator.set_state(state["generator"])
            self._order = state["order"].clone()
            self._pos = int(state["pos"])
            self.step = int(state["step"])
            self.history = list(state.get("history", []))
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise InputError(f"checkpoint does not match this training run ({type(exc).__name__}: {exc})") from None


# ---------------------------------------------------------------------------------------------------- the loop
@dataclass
class Trained:
    """What :func:`train` hands back: the trained scene and its figures (nothing of it is on disk).

    Attributes:
        cloud: the trained parameters as a cloud.
        metrics: mean PSNR and SSIM of the held-out views at the end (empty without held-out views).
        history: loss, PSNR and count every 10 steps, held-out figures every ``eval_every`` steps and at the end.
        seconds: wall time of the steps run by this call.
        steps_run: steps run by this call (fewer than the iterations when it continued a restored state).
    """

    cloud: GaussianCloud
    metrics: dict[str, float]
    history: list[dict[str, float]]
    seconds: float
    steps_run: int

    @property
    def seconds_per_iteration(self) -> float:
        return self.seconds / self.steps_run if self.steps_run else 0.0


def train(trainer: Trainer, *, progress: ProgressFactory = null_progress,
          on_step: Callable[[Trainer, dict[str, float]], None] | None = None,
          on_checkpoint: Callable[[Trainer], None] | None = None) -> Trained:
    """Return the scene trained from the trainer's state (its dataset, parameters, renderer and config) to
    ``config.iterations`` steps; the trainer holds the final state.

    Args:
        trainer: a fresh :class:`Trainer`, or one whose :meth:`Trainer.load_state_dict` restored a checkpoint.
        progress: progress factory (the bar shows loss, PSNR and Gaussian count).
        on_step: called after every step (tests use it to interrupt a run).
        on_checkpoint: called every ``checkpoint_every`` steps and after the last one, with the trainer whose
            :meth:`Trainer.state_dict` is the resumable state (the run layer writes it; the loop names no file).
    """
    config = trainer.config
    start_step = trainer.step
    t0 = time.perf_counter()
    with progress(total=config.iterations, desc="train", initial=start_step) as bar:
        while trainer.step < config.iterations:
            info = trainer.train_step()
            if trainer.step % 10 == 0 or trainer.step == config.iterations:
                trainer.history.append({k: float(v) for k, v in info.items()})
            if config.eval_every and trainer.step % config.eval_every == 0 and trainer.step < config.iterations:
                ev = trainer.evaluate()
                if ev:
                    trainer.history.append({"step": float(trainer.step), "eval_psnr": ev["psnr"],
                                            "eval_ssim": ev["ssim"]})
            if on_checkpoint is not None and (trainer.step % config.checkpoint_every == 0
                                              or trainer.step == config.iterations):
                on_checkpoint(trainer)
            bar.update(1)
            bar.set_postfix_str(f"loss {info['loss']:.4f} psnr {info['psnr']:.2f} n {info['count']}", refresh=False)
            if on_step is not None:
                on_step(trainer, info)
    seconds = time.perf_counter() - t0
    metrics = trainer.evaluate()
    if metrics:
        trainer.history.append({"step": float(trainer.step), "eval_psnr": metrics["psnr"],
                                "eval_ssim": metrics["ssim"]})
    return Trained(trainer.to_cloud(), metrics, trainer.history, seconds, trainer.step - start_step)


def config_with(config: TrainConfig, **changes: Any) -> TrainConfig:
    """Return ``config`` with top-level fields or strategy fields (``cap_max=...``) changed."""
    strategy_fields = set(asdict(config.strategy))
    strat = {k: v for k, v in changes.items() if k in strategy_fields and v is not None}
    top = {k: v for k, v in changes.items() if k not in strategy_fields and v is not None}
    if strat:
        top["strategy"] = replace(config.strategy, **strat)
    return replace(config, **top)
