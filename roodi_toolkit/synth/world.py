"""The :class:`Scene` type: a generated scene's objects, ground, lights and environment.

:mod:`roodi_toolkit.synth.scene` builds it (and re-exports it), :mod:`roodi_toolkit.synth.tracer` renders it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError
from .objects import Light, Part, SceneObject

__all__ = ["Scene"]


@dataclass
class Scene:
    """A generated scene: objects on a ground, lights and an environment.

    Attributes:
        preset: the preset's name.
        seed: the seed it was built from.
        objects: the objects, ids 1..N in order.
        ground: the ground part (id 0 in masks).
        lights: the lights.
        ambient: linear RGB ambient light.
        sky: (horizon, zenith) sRGB colours of the environment seen by rays that hit nothing.
    """

    preset: str
    seed: int
    objects: list[SceneObject]
    ground: Part = field(repr=False)
    lights: list[Light] = field(repr=False)
    ambient: tuple[float, float, float]
    sky: tuple[tuple[float, float, float], tuple[float, float, float]]

    @property
    def targets(self) -> list[SceneObject]:
        """The target objects."""
        return [o for o in self.objects if o.is_target]

    def object(self, object_id: int) -> SceneObject:
        """Return the object with this id."""
        for o in self.objects:
            if o.id == object_id:
                return o
        raise ConfigError(f"scene has no object with id {object_id}")

    @property
    def bounds(self) -> np.ndarray:
        """``[2, 3]`` box around all objects (not the ground)."""
        b = np.stack([o.bounds for o in self.objects])
        return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])
