"""The photo check of the local prune (:mod:`.photos` says what it does): render the photos' views with and without
the flagged Gaussians and share each pixel's change of error among them. Imports torch and the renderer, so the
prune loads it only when there are photos (:func:`roodi_toolkit.prune.scene.prune_cloud`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..params import GaussianParams
from ..progress import ProgressFactory, null_progress
from ..render.renderer import resolve_renderer
from .photos import MATCH_RATIO, Photos


def _psnr(mse: float) -> float:
    return float("inf") if mse <= 0 else -10.0 * float(np.log10(mse))


def _squared_error(rgb: torch.Tensor, alpha: torch.Tensor, photo: torch.Tensor, photo_alpha: torch.Tensor | None,
                   background: torch.Tensor) -> torch.Tensor:
    """Return the per-pixel squared error ``[H, W]`` of a rendering on black (``rgb``, ``alpha``) against a photo.

    Without the photo's alpha: on the photos' background. With it: on black plus on white, from premultiplied colours.
    """
    if photo_alpha is None:
        return ((rgb + (1 - alpha) * background - photo) ** 2).sum(-1)
    pa = photo_alpha[..., None]
    photo_black = photo - (1 - pa) * background
    return ((rgb - photo_black) ** 2).sum(-1) + ((rgb + (1 - alpha) - photo_black - (1 - pa)) ** 2).sum(-1)


@dataclass(frozen=True)
class PhotoCheck:
    """What the photo check measured.

    Attributes:
        support: ``[N]`` float64 ``support_i`` (module docstring); 0 for Gaussians not flagged or never seen.
        psnr: PSNR of the whole cloud's renderings against the photos, from the mean squared error over the views (on
            black and white for RGBA photos).
        psnr_empty: the same for an empty rendering (the background alone).
        views: views rendered.
    """

    support: np.ndarray
    psnr: float
    psnr_empty: float
    views: int


def photo_support(cloud: GaussianCloud, flagged: np.ndarray, photos: Photos, *, renderer=None,
                  progress: ProgressFactory = null_progress) -> PhotoCheck:
    """Return how much the photos support each flagged Gaussian (module docstring).

    Raises:
        ConfigError: the cloud does not explain the photos (:data:`MATCH_RATIO`): another scene or another frame.
    """
    renderer = resolve_renderer(renderer)
    n = len(cloud)
    support = torch.zeros(n, dtype=torch.float64)
    flagged = np.asarray(flagged, dtype=bool)
    full = GaussianParams.from_cloud(cloud)
    cut = GaussianParams.from_cloud(cloud.select(~flagged))
    background = torch.tensor(photos.background, dtype=torch.float32)
    black = (0.0, 0.0, 0.0)
    mse_full, mse_empty = [], []
    with progress(total=len(photos.cameras), desc="photo check") as bar:
        for v, camera in enumerate(photos.cameras):
            photo = photos.images[v].float()
            photo_alpha = None if photos.alphas is None else photos.alphas[v].float()
            ones = torch.ones(n, 1, dtype=full.dtype, requires_grad=True)
            out = renderer.render(replace(full, features=ones), camera, background=black)
            rgb, alpha = out.rgb.detach().float(), out.alpha.detach().float()
            err_full = _squared_error(rgb, alpha, photo, photo_alpha, background)
            zero = torch.zeros_like(rgb[..., :1])
            err_empty = _squared_error(torch.zeros_like(rgb), zero, photo, photo_alpha, background)
            channels = 3 if photo_alpha is None else 6
            mse_full.append(float(err_full.mean()) / channels)
            mse_empty.append(float(err_empty.mean()) / channels)
            if flagged.any():
                with torch.no_grad():
                    without = renderer.render(cut, camera, background=black)
                err_cut = _squared_error(without.rgb.float(), without.alpha.float(), photo, photo_alpha, background)
                delta = (err_cut - err_full).to(out.features.dtype)
                (grad,) = torch.autograd.grad((out.features[..., 0] * delta).sum(), ones)
                support += grad[:, 0].double()
            bar.update(1)
    fit, empty = float(np.mean(mse_full)), float(np.mean(mse_empty))
    if not fit < MATCH_RATIO * empty:
        raise ConfigError(f"the cloud does not match the photos ({photos.source}): its renderings from their cameras "
                          f"are {_psnr(fit):.1f} dB against {_psnr(empty):.1f} dB for an empty "
                          f"picture; is it in their frame? give --photos none to prune without them")
    values = support.numpy()
    values[~flagged] = 0.0
    return PhotoCheck(values, _psnr(fit), _psnr(empty), len(photos.cameras))
