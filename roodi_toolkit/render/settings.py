"""The settings of an orbit around a cloud (:func:`~roodi_toolkit.render.views.framing_orbit`), declared once each
(:func:`roodi_toolkit.settings.setting`): ``roodi-toolkit render``'s orbit options are made from them. A module of its
own so that declaring the options does not import PyTorch (``views.py`` does)."""

from __future__ import annotations

from dataclasses import dataclass

from ..settings import check_settings, documented, setting

DEFAULT_ORBIT_VIEWS = 8
"""Views of an orbit when neither a number of views nor a dataset's cameras are given."""


@documented
@dataclass(frozen=True)
class OrbitSettings:
    """Views on a circle around the cloud's centre, looking at it."""

    # one view per 0.1 degree at most
    orbit: int | None = setting(None, "Render N views on a circle around the cloud (default 8 when --cameras is not "
                                "given).", low=1, high=3600)
    elevation: float = setting(20.0, "Orbit elevation in degrees.")
    radius: float | None = setting(None, "Orbit radius in scene units (default: frame the central 95% of the "
                                   "cloud).", low=0, low_open=True)
    fov: float = setting(50.0, "Orbit horizontal field of view in degrees.", low=1, high=179)

    def __post_init__(self) -> None:
        check_settings(self)

    @property
    def views(self) -> int:
        """The number of views: ``orbit``, or :data:`DEFAULT_ORBIT_VIEWS` when unset."""
        return self.orbit or DEFAULT_ORBIT_VIEWS
