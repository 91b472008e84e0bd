"""Shared fixtures: tiny seeded clouds and a CLI runner that goes through main() (exit codes included)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pytest

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")


def make_cloud(n: int = 50, sh_degree: int = 0, seed: int = 0, extras: bool = False):
    from roodi_toolkit import GaussianCloud

    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2
    ex = {}
    if extras:
        ex = {"segment_id": rng.integers(0, 5, n).astype(np.int32), "weight": rng.random(n).astype(np.float64),
              "flag": rng.integers(0, 2, n).astype(np.uint8)}
    return GaussianCloud(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.normal(-3, 0.5, size=(n, 3)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh_dc=rng.normal(size=(n, 3)).astype(np.float32),
        sh_rest=rng.normal(size=(n, k - 1, 3)).astype(np.float32),
        extras=ex,
    )


@pytest.fixture
def cloud_factory():
    return make_cloud


@dataclass
class CliResult:
    exit_code: int
    stdout: str
    stderr: str


@pytest.fixture
def run_cli(capsys, monkeypatch):
    """Run ``roodi-toolkit ARGS`` in-process through main() and capture its exit code and output. The line a first
    render says when it compiles the kernels is left out (what the tests read on stderr must not depend on whether
    numba's cache was warm: ``tests/render/test_first_compile.py`` checks that line)."""
    from roodi_toolkit.cli.main import main

    monkeypatch.setattr("roodi_toolkit.render.fast.uncompiled", lambda *dispatchers: [])

    def run(*args: str) -> CliResult:
        capsys.readouterr()
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return CliResult(code, out.out, out.err)

    return run


@pytest.fixture(scope="session")
def tiny_kitchen(tmp_path_factory):
    """A 32x32 generated kitchen (10 training views, 3 targets) shared by the pipeline tests."""
    from roodi_toolkit.synth.scene import SceneSettings, make_scene

    root = tmp_path_factory.mktemp("scene") / "kitchen"
    make_scene(root, "kitchen", seed=3, settings=SceneSettings(width=32, height=32, train_views=10, test_views=2,
                                                               supersample=1, n_objects=5, n_targets=3))
    return root
