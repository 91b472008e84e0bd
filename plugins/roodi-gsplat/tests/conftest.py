"""Make ``roodi_gsplat`` importable from a checkout even when the plugin is not installed."""

import sys
from pathlib import Path

try:
    import roodi_gsplat  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
