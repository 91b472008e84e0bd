"""The :class:`SDXLInpainter`: roodi-toolkit's inpainter interface on top of diffusers' SD-XL inpainting pipeline.

The paper inpaints the four object-centred views, tiled 2x2, with "SD-XL Inpainting 0.1"
(``diffusers/stable-diffusion-xl-1.0-inpainting-0.1``) and no prompt. Weights are never downloaded: they come from a
local folder (``model=PATH`` or ``$ROODI_SDXL_MODEL``) or from the local Hugging Face hub cache, loaded with
``local_files_only=True``. diffusers is imported lazily, so the plugin loads (and ``roodi-toolkit plugins`` lists it)
without it.
"""

from __future__ import annotations

import os
import warnings
from typing import Any, Optional

import numpy as np
import torch
from torch import Tensor

from roodi_toolkit.errors import PluginError
from roodi_toolkit.pipeline.inpaint import Inpainter

MODEL_ID = "diffusers/stable-diffusion-xl-1.0-inpainting-0.1"
"""The hub id of SD-XL Inpainting 0.1, looked up in the local hub cache only."""
ENV_MODEL = "ROODI_SDXL_MODEL"
INSTALL_HINT = "install it with `pip install roodi-sdxl` (pulls diffusers and transformers)"


def _import_diffusers() -> Any:
    try:
        import diffusers
    except ImportError as exc:
        raise PluginError(f"the sdxl inpainter needs diffusers ({exc}); {INSTALL_HINT}") from None
    return diffusers


def local_weights() -> str | None:
    """Return where the default weights are on disk (``$ROODI_SDXL_MODEL``'s folder, or the local Hugging Face
    cache's copy of :data:`MODEL_ID`), or None; nothing is downloaded."""
    given = os.environ.get(ENV_MODEL)
    if given:
        return given if os.path.isfile(os.path.join(given, "model_index.json")) else None
    try:
        from huggingface_hub import try_to_load_from_cache
    except ImportError:
        return None
    found = try_to_load_from_cache(MODEL_ID, "model_index.json")
    return found if isinstance(found, str) else None


def native_size(height: int, width: int, resolution: int) -> tuple[int, int]:
    """Return the (height, width) the model runs at: longer side ``resolution``, both multiples of 8.

    Example:
        >>> native_size(96, 96, 1024), native_size(100, 50, 1024)
        ((1024, 1024), (1024, 512))
    """
    scale = resolution / max(height, width)
    return max(8, round(height * scale / 8) * 8), max(8, round(width * scale / 8) * 8)


class SDXLInpainter(Inpainter):
    """Inpaint with SD-XL Inpainting 0.1 through diffusers' ``StableDiffusionXLInpaintPipeline``.

    Each image (the 2x2 grid of views) is resized to the model's native resolution (1024 on the longer side, so a
    square grid runs at 1024x1024), inpainted, and resized back; the caller's :meth:`Inpainter.inpaint` then keeps
    every unmasked pixel exactly as it was. Sampling settings default to the model card's (20 steps, strength 0.99,
    guidance 8.0) with an empty prompt, as in the paper.

    Args:
        model: a local folder holding the pipeline (``save_pretrained`` layout) or a hub id looked up in the local
            cache only; default ``$ROODI_SDXL_MODEL`` or :data:`MODEL_ID`.
        pipeline: an already-built ``StableDiffusionXLInpaintPipeline`` (takes precedence over ``model``).
        resolution: the model's native resolution (longer side of what it is fed).
        steps: denoising steps.
        strength: how much of the masked region's content is replaced (0.99: almost fully re-drawn).
        guidance_scale: classifier-free guidance.
        seed: seed of the sampling noise; the same inputs and seed give the same output.
        device: torch device (default CUDA when available, else CPU).
        dtype: weight dtype (default float16 on CUDA, float32 on CPU).
    """

    name = "sdxl"

    def __init__(self, *, model: Optional[str] = None, pipeline: Any = None, resolution: int = 1024, steps: int = 20,
                 strength: float = 0.99, guidance_scale: float = 8.0, seed: int = 0, device: Optional[str] = None,
                 dtype: Optional[torch.dtype] = None) -> None:
        if resolution < 8 or steps < 1 or not 0 < strength <= 1:
            raise PluginError(f"sdxl inpainter: need resolution >= 8, steps >= 1, 0 < strength <= 1; got "
                              f"{resolution}, {steps}, {strength}")
        self.model = model or os.environ.get(ENV_MODEL) or MODEL_ID
        self.resolution = int(resolution)
        self.steps = int(steps)
        self.strength = float(strength)
        self.guidance_scale = float(guidance_scale)
        self.seed = int(seed)
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.dtype = dtype or (torch.float16 if self.device.type == "cuda" else torch.float32)
        self._pipeline = pipeline

    @classmethod
    def available(cls) -> tuple[bool, str]:
        try:
            _import_diffusers()
        except PluginError as exc:
            return False, str(exc)
        return True, ""

    @classmethod
    def status(cls) -> tuple[str, str]:
        """Return ``("installed", "")`` when diffusers is there and the default weights are on disk
        (``$ROODI_SDXL_MODEL``, else :data:`MODEL_ID` in the local Hugging Face cache), ``("needs a package", ...)``
        without diffusers, ``("needs weights", ...)`` without the weights."""
        ok, why = cls.available()
        if not ok:
            return "needs a package", why
        where = local_weights()
        if where is None:
            return "needs weights", (f"no SD-XL Inpainting 0.1 weights in ${ENV_MODEL} or the local Hugging Face "
                                     f"cache; download {MODEL_ID} (huggingface-cli download {MODEL_ID}) or give "
                                     "--inpainter-option model=PATH")
        return "installed", ""

    @property
    def pipeline(self) -> Any:
        """The diffusers pipeline, loaded from local files on first use.

        Raises:
            PluginError: diffusers is missing, or the weights are not in the given folder / the local hub cache.
        """
        if self._pipeline is None:
            diffusers = _import_diffusers()
            where = (f"folder {self.model}" if os.path.isdir(self.model)
                     else f"{self.model!r} in the local Hugging Face cache")
            try:
                with warnings.catch_warnings():  # newer diffusers renamed torch_dtype to dtype; older ones lack dtype
                    warnings.simplefilter("ignore", FutureWarning)
                    pipe = diffusers.StableDiffusionXLInpaintPipeline.from_pretrained(
                        self.model, torch_dtype=self.dtype, local_files_only=True)
            except Exception as exc:  # noqa: BLE001 - diffusers raises several types for missing files
                first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                raise PluginError(
                    f"sdxl inpainter: cannot load SD-XL Inpainting 0.1 from {where} (nothing is downloaded at run "
                    f"time): {first}; fetch it on a connected machine with `huggingface-cli download {MODEL_ID}` or "
                    f"pass model=PATH / set ${ENV_MODEL}") from None
            self._pipeline = pipe
        self._pipeline.to(self.device)
        if hasattr(self._pipeline, "set_progress_bar_config"):
            self._pipeline.set_progress_bar_config(disable=True)
        return self._pipeline

    def fill(self, images: Tensor, masks: Tensor, prompt: str) -> Tensor:
        from PIL import Image

        pipe = self.pipeline
        b, h, w, _ = images.shape
        nh, nw = native_size(h, w, self.resolution)
        out = torch.empty_like(images)
        for i in range(b):
            image = Image.fromarray((images[i].numpy() * 255 + 0.5).astype(np.uint8)).resize(
                (nw, nh), Image.Resampling.BICUBIC)
            # nearest keeps the mask binary; the pipeline binarises at 0.5 anyway
            mask = Image.fromarray(masks[i].numpy().astype(np.uint8) * 255).resize((nw, nh), Image.Resampling.NEAREST)
            generator = torch.Generator(device="cpu").manual_seed(self.seed)
            result = pipe(prompt=prompt, image=image, mask_image=mask, height=nh, width=nw,
                          num_inference_steps=self.steps, strength=self.strength,
                          guidance_scale=self.guidance_scale, generator=generator, output_type="np").images[0]
            result = torch.as_tensor(np.asarray(result, dtype=np.float32)).permute(2, 0, 1)[None]
            back = torch.nn.functional.interpolate(result, size=(h, w), mode="bilinear", antialias=True,
                                                   align_corners=False)
            out[i] = back[0].permute(1, 2, 0).clamp(0, 1)
        return out
