"""Fixtures of the hostile suite: one tiny world of inputs (clouds in every written format, a generated scene, a
Blender dataset with a model folder and its distillation), built once, and the checks every case makes.

Every case asserts: the exit code, exactly one line on stderr that names the file or option at fault (never an
"unexpected" error, never a traceback), and every input byte-identical afterwards (``world.unchanged()``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.object_scene import tree_digest, write_object_scene

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")


@dataclass
class World:
    root: Path
    ply: Path  # a 60-Gaussian cloud, SH degree 1
    spz: Path
    cply: Path  # compressed PLY
    data: Path  # Blender dataset with masks (object scene)
    model: Path  # its model folder (as train writes it)
    dist: Path  # its distillation (as distill writes it)
    gen: Path  # a make-scene folder (evaluate's DATA_DIR)
    digest: dict

    def unchanged(self) -> bool:
        """True if every input is byte-identical to when the world was built, nothing added or removed."""
        return tree_digest(self.root) == self.digest


@pytest.fixture(scope="session")
def world(tmp_path_factory) -> World:
    from roodi_toolkit.cli.main import main
    from roodi_toolkit.io.splat import write_cloud
    from roodi_toolkit.synth.scene import SceneSettings, make_scene
    from tests.conftest import make_cloud

    root = tmp_path_factory.mktemp("hostile_world")
    cloud = make_cloud(60, sh_degree=1, seed=5)
    ply = write_cloud(cloud, root / "cloud.ply")
    spz = write_cloud(cloud, root / "cloud.spz")
    cply = write_cloud(cloud, root / "cloud.compressed.ply")
    data, model, _ = write_object_scene(root / "objects", size=16, views=6)
    dist = root / "dist"
    assert main(["distill", str(model), str(data), str(dist), "--iterations", "2", "-q"]) == 0
    gen = root / "gen"
    make_scene(gen, "kitchen", seed=3, settings=SceneSettings(width=16, height=16, train_views=3, test_views=2,
                                                              supersample=1, n_objects=5, n_targets=1))
    return World(root, Path(ply), Path(spz), Path(cply), data, model, dist, gen, tree_digest(root))


def one_error_line(stderr: str) -> str:
    """Return the single line on stderr, failing if there is none, more than one, or it is not a handled error."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}: {stderr!r}"
    line = lines[0]
    assert line.startswith("error: "), line
    assert "unexpected" not in line and "Traceback" not in line, line
    return line


def expect_failure(res, code: int, *needles: str) -> str:
    """Assert exit ``code`` and one stderr line naming every one of ``needles``; return the line."""
    assert res.exit_code == code, (res.exit_code, res.stderr, res.stdout[-300:])
    line = one_error_line(res.stderr)
    for needle in needles:
        assert needle in line, (needle, line)
    return line
