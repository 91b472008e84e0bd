"""The Markov-chain Monte Carlo (MCMC) densification strategy of 3DGS-MCMC (Kheradmand et al. 2024), as in gsplat.

The strategy is a frozen dataclass of hyperparameters; what changes during training lives in :class:`MCMCState`.
Parameter edits that must also touch the optimizer state (relocation, growth) are the small no-grad functions at the
bottom of this module, in one place.

Parameters are a :class:`~roodi_toolkit.params.GaussianParams` (or any mutable mapping of the same names to
``torch.nn.Parameter``): ``means [N, 3]``, ``quats_wxyz [N, 4]``, ``log_scales [N, 3]``, ``opacity_logits [N]``,
``sh_dc [N, 3]``, ``sh_rest [N, K-1, 3]`` and optionally ``features [N, F]``; every per-Gaussian tensor follows the
edits. Optimizers is a dict with one optimizer per parameter name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, MutableMapping

import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix
from torch import Tensor

from .train_kernels import covariance_noise
from ..settings import check_settings, documented, setting

Params = MutableMapping[str, Tensor]
"""A :class:`~roodi_toolkit.params.GaussianParams` or a name -> Parameter mapping with its names."""

N_MAX = 51
"""Largest number of copies a Gaussian is split into in one relocation (as gsplat)."""


@documented
@dataclass(frozen=True)
class MCMCStrategy:
    """Hyperparameters of MCMC densification. Defaults are those of 3DGS-MCMC / gsplat's ``MCMCStrategy`` (the
    position noise's scale 5e5, relocation and growth from iteration 500 to 25,000 every 100, dead below opacity
    0.005, 5% growth, both regulariser weights 0.01)."""

    cap_max: int = setting(1_000_000, "Most Gaussians MCMC may grow to.", low=1)
    noise_lr: float = setting(5e5, "Scale of the position noise, times the position learning rate.", low=0,
                              cli=False)
    refine_start_iter: int = setting(500, "First iteration of relocation and growth.", low=0, cli=False)
    refine_stop_iter: int = setting(25_000, "Iteration after which relocation and growth stop.", low=0, cli=False)
    refine_every: int = setting(100, "Relocate and grow every this many iterations.", low=1, cli=False)
    min_opacity: float = setting(0.005, "Gaussians below this opacity are dead and relocated.", low=0, high=1,
                                 high_open=True, cli=False)
    grow_rate: float = setting(0.05, "Growth per refinement step, a fraction of the count.", low=0, cli=False)
    opacity_reg: float = setting(0.01, "Weight of the mean-opacity regulariser.", low=0, cli=False)
    scale_reg: float = setting(0.01, "Weight of the mean-scale regulariser.", low=0, cli=False)

    def __post_init__(self) -> None:
        check_settings(self)

    def initialize_state(self) -> "MCMCState":
        """Return a fresh training state for this strategy."""
        return MCMCState()

    def is_refine_step(self, step: int) -> bool:
        """Return whether relocation and growth happen after ``step`` (0-based, as gsplat counts)."""
        return (self.refine_start_iter < step < self.refine_stop_iter) and step % self.refine_every == 0

    def regularization(self, params: Params) -> Tensor:
        """Return opacity_reg * mean(opacity) + scale_reg * mean(scale), the MCMC regularisers (activated values)."""
        reg = self.opacity_reg * torch.sigmoid(params["opacity_logits"]).mean()
        return reg + self.scale_reg * torch.exp(params["log_scales"]).mean()

    def step_post_backward(self, params: Params, optimizers: dict[str, torch.optim.Optimizer],
                           state: "MCMCState", step: int, means_lr: float,
                           generator: torch.Generator | None = None) -> dict[str, int]:
        """Relocate dead Gaussians and grow (on refinement steps), then add position noise; return what was done.

        Called after ``loss.backward()`` and the optimizer step, as gsplat's trainer does.

        Args:
            params: the model parameters (edited in place, replaced by new Parameters when the count changes).
            optimizers: one optimizer per parameter (their state follows the edits).
            state: the strategy's training state.
            step: the 0-based iteration just done.
            means_lr: the current learning rate of the means (the noise scales with it).
            generator: random generator for sampling and noise (seeded by the trainer for reproducibility).
        """
        report = {"relocated": 0, "added": 0}
        if self.is_refine_step(step):
            report["relocated"] = relocate_dead(params, optimizers, self.min_opacity, generator)
            report["added"] = grow(params, optimizers, self.cap_max, self.grow_rate, self.min_opacity, generator)
            state.history.append((step, len(params["means"]), report["relocated"], report["added"]))
        inject_position_noise(params, means_lr * self.noise_lr, generator)
        return report


@dataclass
class MCMCState:
    """What MCMC densification changes during training: a log of (step, count, relocated, added)."""

    history: list[tuple[int, int, int, int]] = field(default_factory=list)

    def state_dict(self) -> dict:
        return {"history": [list(h) for h in self.history]}

    def load_state_dict(self, d: dict) -> None:
        self.history = [tuple(h) for h in d.get("history", [])]


# ------------------------------------------------------------------------------------------------ relocation maths
def _binomials(n_max: int = N_MAX, dtype: torch.dtype = torch.float64) -> Tensor:
    """``[n_max, n_max]`` table of binom(n, k)."""
    table = torch.zeros(n_max, n_max, dtype=dtype)
    for n in range(n_max):
        for k in range(n + 1):
            table[n, k] = math.comb(n, k)
    return table


def compute_relocation(opacities: Tensor, scales: Tensor, ratios: Tensor,
                       n_max: int = N_MAX) -> tuple[Tensor, Tensor]:
    """Return the opacity ``[M]`` and scales ``[M, 3]`` of each of ``ratios[i]`` copies replacing one Gaussian.

    Equation 9 of 3DGS-MCMC: the new opacity keeps the composited opacity at the centre,
    ``1 - (1 - o_new)^n = o``, and the new scale keeps the integral of the composited opacity along a ray,
    ``s_new = o * s / sum_{i=1..n} sum_{k=0..i-1} binom(i-1, k) (-1)^k o_new^(k+1) / sqrt(k+1)``.

    Args:
        opacities: ``[M]`` activated opacities in (0, 1).
        scales: ``[M, 3]`` activated scales.
        ratios: ``[M]`` integer number of copies (clamped to [1, n_max]).
    """
    ratios = ratios.clamp(1, n_max).to(torch.int64)
    o = opacities.to(torch.float64).clamp(0.0, 1.0 - 1e-12)
    new_o = 1.0 - torch.pow(1.0 - o, 1.0 / ratios.to(torch.float64))
    binoms = _binomials(n_max + 1)
    k = torch.arange(n_max, dtype=torch.float64)
    # sum_{i=1..n} binom(i-1, k) = binom(n, k+1); so denom = sum_{k=0..n-1} binom(n, k+1) (-1)^k o^(k+1) / sqrt(k+1)
    coeff = binoms[ratios][:, 1:]  # binom(n, k+1) for k = 0..n_max-1
    terms = coeff * ((-1.0) ** k) * new_o[:, None] ** (k + 1) / torch.sqrt(k + 1)
    denom = (terms * (k[None, :] < ratios[:, None])).sum(dim=1)
    new_s = (o / denom)[:, None] * scales.to(torch.float64)
    return new_o.to(opacities.dtype), new_s.to(scales.dtype)


# ------------------------------------------------------------------------------------------------ parameter edits
_Edit = Callable[[str, Tensor], Tensor]


@torch.no_grad()
def update_params_and_optimizers(params: Params, optimizers: dict[str, torch.optim.Optimizer],
                                 param_fn: _Edit, state_fn: _Edit) -> None:
    """Replace every parameter by ``param_fn(name, p)`` and each optimizer state tensor by ``state_fn(name, v)``."""
    for name in list(params):
        old = params[name]
        new = torch.nn.Parameter(param_fn(name, old.data), requires_grad=old.requires_grad)
        params[name] = new
        opt = optimizers.get(name)
        if opt is None:
            continue
        for group in opt.param_groups:
            group["params"] = [new if p is old else p for p in group["params"]]
        if old in opt.state:
            st = opt.state.pop(old)
            opt.state[new] = {k: (state_fn(name, v) if isinstance(v, Tensor) and v.dim() > 0 else v)
                              for k, v in st.items()}


def _sample_by_opacity(opacities: Tensor, candidates: Tensor, n: int, generator: torch.Generator | None) -> Tensor:
    probs = opacities[candidates].clamp_min(0)
    if probs.sum() <= 0:
        probs = torch.ones_like(probs)
    picked = torch.multinomial(probs, n, replacement=True, generator=generator)
    return candidates[picked]


@torch.no_grad()
def _split_into_copies(params: Params, sampled: Tensor,
                       min_opacity: float) -> tuple[Tensor, Tensor, Tensor]:
    """Return the unique sampled sources and their new opacity logits and log-scales after sharing with copies."""
    counts = torch.bincount(sampled, minlength=len(params["means"]))
    sources = torch.unique(sampled)
    ratios = counts[sources] + 1  # the source itself plus its copies
    new_o, new_s = compute_relocation(torch.sigmoid(params["opacity_logits"][sources]),
                                      torch.exp(params["log_scales"][sources]), ratios)
    new_o = new_o.clamp(min=min_opacity, max=1.0 - torch.finfo(new_o.dtype).eps)
    return sources, torch.logit(new_o), torch.log(new_s)


def _with_split_sources(name: str, p: Tensor, sources: Tensor, new_logits: Tensor, new_log_scales: Tensor) -> Tensor:
    """Return a copy of parameter ``name`` with the split sources' opacity or scale set to their shared value."""
    p = p.clone()
    if name == "opacity_logits":
        p[sources] = new_logits.to(p.dtype)
    elif name == "log_scales":
        p[sources] = new_log_scales.to(p.dtype)
    return p


@torch.no_grad()
def relocate_dead(params: Params, optimizers: dict[str, torch.optim.Optimizer],
                  min_opacity: float, generator: torch.Generator | None = None) -> int:
    """Move Gaussians with opacity <= min_opacity onto live ones sampled by opacity; return how many moved."""
    opac = torch.sigmoid(params["opacity_logits"])
    dead = torch.nonzero(opac <= min_opacity).squeeze(1)
    alive = torch.nonzero(opac > min_opacity).squeeze(1)
    if len(dead) == 0 or len(alive) == 0:
        return 0
    sampled = _sample_by_opacity(opac, alive, len(dead), generator)
    sources, new_logits, new_log_scales = _split_into_copies(params, sampled, min_opacity)
    touched = torch.cat([sources, dead])

    def param_fn(name: str, p: Tensor) -> Tensor:
        p = _with_split_sources(name, p, sources, new_logits, new_log_scales)
        p[dead] = p[sampled]
        return p

    def state_fn(name: str, v: Tensor) -> Tensor:
        v = v.clone()
        v[touched] = 0
        return v

    update_params_and_optimizers(params, optimizers, param_fn, state_fn)
    return int(len(dead))


@torch.no_grad()
def grow(params: Params, optimizers: dict[str, torch.optim.Optimizer], cap_max: int,
         grow_rate: float, min_opacity: float, generator: torch.Generator | None = None) -> int:
    """Add min(cap_max, (1+grow_rate) N) - N Gaussians as copies of ones sampled by opacity; return how many."""
    n = len(params["means"])
    n_new = max(0, min(cap_max, int((1.0 + grow_rate) * n)) - n)
    if n_new == 0:
        return 0
    opac = torch.sigmoid(params["opacity_logits"])
    sampled = _sample_by_opacity(opac, torch.arange(n), n_new, generator)
    sources, new_logits, new_log_scales = _split_into_copies(params, sampled, min_opacity)

    def param_fn(name: str, p: Tensor) -> Tensor:
        p = _with_split_sources(name, p, sources, new_logits, new_log_scales)
        return torch.cat([p, p[sampled]])

    def state_fn(name: str, v: Tensor) -> Tensor:
        v = v.clone()
        v[sources] = 0
        return torch.cat([v, torch.zeros((n_new, *v.shape[1:]), dtype=v.dtype)])

    update_params_and_optimizers(params, optimizers, param_fn, state_fn)
    return n_new


def noise_gate(opacities: Tensor, k: float = 100.0, x0: float = 0.995) -> Tensor:
    """Return the factor gating position noise: sigmoid(k ((1 - o) - x0)), ~1 for transparent, ~0 for opaque."""
    return torch.sigmoid(k * ((1.0 - opacities) - x0))


@torch.no_grad()
def inject_position_noise(params: Params, scale: float,
                          generator: torch.Generator | None = None) -> None:
    """Add Gaussian noise to the means, shaped by each covariance and gated by opacity (3DGS-MCMC, Eq. 10).

    The noise is ``Sigma_i n_i`` with ``n_i ~ N(0, 1) * gate(o_i) * scale``; the product with each covariance is
    one compiled pass (:func:`~roodi_toolkit.pipeline.train_kernels.covariance_noise`;
    :func:`covariance_noise_reference` is the same in torch)."""
    means = params["means"]
    opac = torch.sigmoid(params["opacity_logits"])
    noise = torch.randn(means.shape, generator=generator, dtype=means.dtype) * noise_gate(opac)[:, None] * scale
    means.add_(covariance_noise(params["quats_wxyz"], params["log_scales"], noise))


def covariance_noise_reference(quats_wxyz: Tensor, log_scales: Tensor, vectors: Tensor) -> Tensor:
    """Return ``R diag(s^2) R^T v`` ``[N, 3]`` with the ``[N, 3, 3]`` covariances built in torch (the plain version of
    :func:`~roodi_toolkit.pipeline.train_kernels.covariance_noise`, which the tests compare with it)."""
    R = quaternion_to_rotation_matrix(quats_wxyz)  # [N, 3, 3], w,x,y,z, normalised inside
    s2 = torch.exp(2.0 * log_scales)
    covars = R @ torch.diag_embed(s2) @ R.transpose(1, 2)
    return torch.einsum("nij,nj->ni", covars, vectors)
