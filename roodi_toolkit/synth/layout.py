"""The layout of a generated scene: which objects a preset and seed draw, their meshes, and where each stands.

:func:`build_scene` turns a preset and a seed into a :class:`~roodi_toolkit.synth.world.Scene`; one generator, seeded
from both, draws everything in a fixed order (counts, kinds, shapes, wraps, places, lights), so the same arguments
give the same scene bit for bit. :mod:`roodi_toolkit.synth.scene` adds the cameras and writes the scene folder.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ConfigError
from .objects import BUILDERS, MAX_OBJECTS, PRESETS, Part, Preset, SceneObject, _environment, _NOT_TARGETS, _rot
from .world import Scene
from .wraps import WRAPPABLE, wrap_parts

__all__ = ["build_scene"]

_BIG_KINDS = ("bed", "sofa", "blanket", "umbrella", "bench")  # furniture that frames the scene from its edge


def _footprint(parts: list[Part]) -> tuple[float, float]:
    """Return (radius of the xy footprint around the z axis, height)."""
    v = np.concatenate([p.vertices for p in parts])
    return float(np.linalg.norm(v[:, :2], axis=1).max()), float(v[:, 2].max())


def _transform(parts: list[Part], yaw: float, at: np.ndarray) -> list[Part]:
    R = _rot("z", yaw)
    return [Part(p.vertices @ R.T + at, p.triangles, p.material, p.smooth) for p in parts]


def _object_counts(P: Preset, rng: np.random.Generator, n_objects: int | None, n_targets: int | None,
                   occluded: bool) -> tuple[int, int, int]:
    """Return the counts of objects, targets and wraps (one per target when ``occluded``), drawing those not given.

    Raises:
        ConfigError: counts out of range, or too few objects for a wrap per target.
    """
    n = int(n_objects) if n_objects is not None else int(rng.integers(P.n_objects[0], P.n_objects[1] + 1))
    if not 5 <= n <= MAX_OBJECTS:
        raise ConfigError(f"n_objects must be 5 to {MAX_OBJECTS}, got {n}")
    n_t = int(n_targets) if n_targets is not None else (4 if occluded else int(rng.integers(3, 5)))
    if not 1 <= n_t <= 4:
        raise ConfigError(f"n_targets must be 1 to 4, got {n_t}")
    n_wraps = n_t if occluded else 0  # one wrap per target, ids right after the targets'
    if occluded and n_objects is None:
        n = max(n, 2 * n_t)
    if n < n_t + n_wraps:
        raise ConfigError(f"an occluded scene needs at least two objects per target (the target and its wrap): "
                              f"n_objects {n} < 2 x {n_t} targets")
    return n, n_t, n_wraps


def _draw_kinds(P: Preset, rng: np.random.Generator, n: int, n_t: int, n_wraps: int, occluded: bool) -> list[str]:
    """Return the kind of every object: the targets', ``"wrap"`` for each wrap (named once built), then the rest's,
    drawn by the preset's weights with at most one of each kind the preset allows once."""
    kinds_all = sorted(P.catalog)
    weights = np.array([P.catalog[k] for k in kinds_all])
    target_kinds = [k for k in kinds_all if k not in _NOT_TARGETS and (not occluded or k in WRAPPABLE)]
    t_weights = np.array([P.catalog[k] for k in target_kinds])

    def draw(pool: list[str], w: np.ndarray, used: list[str]) -> str:
        ok = np.array([not (k in P.at_most_one and k in used) for k in pool], dtype=float) * w
        return pool[int(rng.choice(len(pool), p=ok / ok.sum()))]

    kinds: list[str] = []
    for _ in range(n_t):
        kinds.append(draw(target_kinds, t_weights, kinds))
    kinds += ["wrap"] * n_wraps
    for _ in range(n - n_t - n_wraps):
        kinds.append(draw(kinds_all, weights, kinds))
    return kinds


def _build_meshes(P: Preset, rng: np.random.Generator, kinds: list[str], n_t: int,
                  n_wraps: int) -> list[list[Part]]:
    """Return every object's mesh parts in its own frame, standing on z = 0; each wrap is fitted to its target as
    built and its entry of ``kinds`` renamed to the wrap's kind."""
    built = []
    for k in kinds:
        if k == "wrap":
            built.append([])
            continue
        glossy = bool(rng.uniform() < P.glossy_fraction)
        parts = BUILDERS[k](rng, glossy)
        lowest = min(float(p.vertices[:, 2].min()) for p in parts)
        for p in parts:  # stand exactly on z = 0 (no part sinks into the ground or floats above it)
            p.vertices = p.vertices - np.array([0.0, 0.0, lowest])
        built.append(parts)
    for j in range(n_wraps):  # the wrap fits its target as built (local coordinates) and moves with it
        kinds[n_t + j], built[n_t + j] = wrap_parts(kinds[j], built[j], rng)
    return built


class _Layout:
    """Objects placed on the ground so far, by rejection sampling against those already standing.

    A target and its wrap are placed as one (the wrap's footprint counts) and the wrap takes its target's place.
    """

    def __init__(self, P: Preset, rng: np.random.Generator, kinds: list[str], built: list[list[Part]], n_t: int,
                 n_wraps: int) -> None:
        self.P, self.rng, self.kinds, self.built = P, rng, kinds, built
        self.n_t, self.n_wraps = n_t, n_wraps
        self.placed: list[dict[str, Any]] = []  # x, y, r, h, z, kind (and a table's free top)
        self.infos: dict[int, dict[str, Any]] = {}
        self.positions: dict[int, tuple[np.ndarray, float]] = {}  # object -> (where it stands [3], yaw)

    def footprint(self, i: int) -> tuple[float, float]:
        """Return object ``i``'s (footprint radius, height), its wrap's included."""
        built = self.built
        return _footprint(built[i] + built[self.n_t + i]) if i < self.n_wraps else _footprint(built[i])

    def collides(self, x: float, y: float, r: float, z: float, h: float) -> bool:
        """Return whether a disc of radius ``r`` at (x, y), from height z to z + h, comes within the preset's gap of
        something placed."""
        for q in self.placed:
            if q["z"] + q["h"] <= z + 1e-6 or z + h <= q["z"] + 1e-6:
                continue  # one stands on something above / below the other
            if math.hypot(x - q["x"], y - q["y"]) < r + q["r"] + self.P.gap:
                return True
        return False

    def try_table(self, r: float, h: float) -> tuple[float, float, float] | None:
        """Return a free spot (x, y, z) on a placed table's top for a small object, drawn with the preset's
        probability, or None."""
        tables = [q for q in self.placed if q["kind"] == "table"]
        if not tables or r > 0.14 or self.rng.uniform() >= self.P.on_table_probability:
            return None
        q = tables[int(self.rng.integers(len(tables)))]
        for _ in range(30):
            x = q["x"] + self.rng.uniform(-1, 1) * max(q["top"][0] - r, 0.0)
            y = q["y"] + self.rng.uniform(-1, 1) * max(q["top"][1] - r, 0.0)
            if not self.collides(x, y, r, q["h"], h):
                return x, y, q["h"]
        return None

    def place(self, i: int, center: tuple[float, float], radius: float, allow_table: bool) -> None:
        """Stand object ``i`` at a free spot in the disc around ``center`` (widened while crowded) or on a table,
        with a random yaw (a table's axis-aligned).

        Raises:
            ConfigError: no free spot found.
        """
        rng, kinds = self.rng, self.kinds
        r, h = self.footprint(i)
        spot = self.try_table(r, h) if allow_table else None
        if spot is None:
            rad = radius
            for attempt in range(400):
                a, s = rng.uniform(0, 2 * math.pi), rad * math.sqrt(rng.uniform())
                x, y = center[0] + s * math.cos(a), center[1] + s * math.sin(a)
                if not self.collides(x, y, r, 0.0, h):
                    spot = (x, y, 0.0)
                    break
                if attempt % 40 == 39:
                    rad *= 1.15  # crowded: widen the disc
            if spot is None:
                raise ConfigError(f"could not place object {i} ({kinds[i]}) without collisions; use fewer objects")
        x, y, z = spot
        yaw = float(rng.uniform(0, 2 * math.pi))
        info: dict[str, Any] = {"x": x, "y": y, "z": z, "r": r, "h": h, "kind": kinds[i]}
        if kinds[i] == "table":
            v = np.concatenate([p.vertices for p in self.built[i]])
            info["top"] = (0.5 * (v[:, 0].max() - v[:, 0].min()) * 0.6, 0.5 * (v[:, 1].max() - v[:, 1].min()) * 0.6)
            info["r"] = r
            yaw = float(rng.choice([0.0, math.pi / 2]))  # axis-aligned so the top's free box stays simple
            info["top"] = info["top"] if yaw == 0.0 else info["top"][::-1]
        self.placed.append(info)
        self.infos[i] = info
        self.positions[i] = (np.array([x, y, z]), yaw)


def _place_objects(P: Preset, rng: np.random.Generator, kinds: list[str], built: list[list[Part]], n_t: int,
                   n_wraps: int) -> dict[int, tuple[np.ndarray, float]]:
    """Return where every object stands and its yaw: large things first (keeps the rejection sampling short), the
    big furniture away from the middle so it frames rather than buries the targets, the targets near the centre,
    an occluder right beside each target, then the rest; each wrap stands where its target does."""
    n = len(kinds)
    layout = _Layout(P, rng, kinds, built, n_t, n_wraps)
    others = sorted(range(n_t + n_wraps, n), key=lambda i: -_footprint(built[i])[0])
    big = [i for i in others if _footprint(built[i])[0] > 0.3]
    small = [i for i in others if i not in big]
    occluders = small[:n_t] if len(small) >= n_t else small
    rest = big + [i for i in small if i not in occluders]
    targets = list(range(n_t))
    positions = layout.positions
    R = P.layout_radius
    for i in big:
        if kinds[i] in _BIG_KINDS:
            layout.place(i, (0.0, 0.0), R, False)
    for i in big:
        if i not in positions:
            layout.place(i, (0.0, 0.0), R * 0.6, False)
    for i in targets:
        layout.place(i, (0.0, 0.0), R * 0.45, True)
    for j, i in enumerate(occluders):
        tx, ty, _ = positions[targets[j % n_t]][0]
        r_t, r_o = layout.infos[targets[j % n_t]]["r"], layout.footprint(i)[0]
        layout.place(i, (tx, ty), r_t + r_o + 0.15, False)
    for i in rest:
        if i not in positions:
            layout.place(i, (0.0, 0.0), R, True)
    for j in range(n_wraps):
        positions[n_t + j] = positions[j]
    return positions


def _scene_objects(kinds: list[str], built: list[list[Part]], positions: dict[int, tuple[np.ndarray, float]],
                   n_t: int) -> list[SceneObject]:
    """Return the placed objects, ids from 1, named by kind and count (``mug_2``), the first ``n_t`` the targets."""
    objects = []
    counters: dict[str, int] = {}
    for i, kind in enumerate(kinds):
        counters[kind] = counters.get(kind, 0) + 1
        at, yaw = positions[i]
        name = f"{kind.replace('pyvista_', '')}_{counters[kind]}"
        source = f"pyvista:{kind[len('pyvista_'):]}" if kind.startswith("pyvista_") else "procedural"
        objects.append(SceneObject(i + 1, name, kind, _transform(built[i], yaw, at), is_target=i < n_t,
                                   source=source))
    return objects


def build_scene(preset: str = "bedroom", seed: int = 0, *, n_objects: int | None = None,
                n_targets: int | None = None, occluded: bool = False) -> Scene:
    """Return a scene of the preset, laid out from the seed (same arguments -> the same scene).

    Targets are placed near the middle and each gets an occluder right beside it, so that in many views of the
    hemisphere around the scene part of every target is hidden.

    Args:
        preset: ``bedroom``, ``kitchen``, ``livingroom`` or ``picnic``.
        seed: random seed of the layout, shapes, colours and lights.
        n_objects: object count (5 to 20), default drawn from the preset's range (at least twice the targets when
            ``occluded``).
        n_targets: target count (1 to 4), default 3 or 4 (4 when ``occluded``).
        occluded: the occluded variant: targets are drawn from the compact kinds
            (:data:`~roodi_toolkit.synth.wraps.WRAPPABLE`) and each stands in a wrap that touches it (a box or
            sleeve open at the top, or a bowl: :func:`~roodi_toolkit.synth.wraps.wrap_parts`), an object of its
            own placed right after the targets (ids ``n_targets + 1 ...``), which hides the target's lower part from
            every training camera. Without it the scene is the same as before the variant existed, bit for bit.

    Raises:
        ConfigError: unknown preset or counts out of range.
    """
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    P = PRESETS[preset]
    rng = np.random.default_rng([int(seed), sorted(PRESETS).index(preset)])  # draws below in this order only
    n, n_t, n_wraps = _object_counts(P, rng, n_objects, n_targets, occluded)
    kinds = _draw_kinds(P, rng, n, n_t, n_wraps, occluded)
    built = _build_meshes(P, rng, kinds, n_t, n_wraps)
    positions = _place_objects(P, rng, kinds, built, n_t, n_wraps)
    objects = _scene_objects(kinds, built, positions, n_t)
    ground, lights, ambient, sky = _environment(P, rng)
    return Scene(preset=preset, seed=int(seed), objects=objects, ground=ground, lights=lights, ambient=ambient, sky=sky)
