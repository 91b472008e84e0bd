"""SD-XL Inpainting 0.1 plugin for roodi-toolkit: registers ``sdxl`` under ``roodi_toolkit.inpainters``."""

from .inpainter import MODEL_ID, SDXLInpainter

__all__ = ["MODEL_ID", "SDXLInpainter"]
