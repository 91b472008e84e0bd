"""gsplat (CUDA) renderer plugin for roodi-toolkit: registers ``gsplat`` under ``roodi_toolkit.renderers``."""

from .renderer import GsplatRenderer

__all__ = ["GsplatRenderer"]
