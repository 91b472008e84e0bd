"""Extreme values that a command handles must not bring NumPy's raw warnings to stderr ("RuntimeWarning: overflow
encountered in exp" and the source line under it): the cases the sweep found, each silenced where it arises, and
the CLI shows no numerical warning unless --debug."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

# (field, value, every Gaussian or one) x commands: the sweep's cases that printed raw warnings on stderr
CASES = [
    ("means", 1e38, "one", "prune"), ("means", 1e38, "one", "prune object"), ("means", 1e38, "one", "inspect"),
    ("log_scales", 1e30, "one", "prune"), ("log_scales", 1e30, "one", "prune statistical"),
    ("log_scales", 1e30, "one", "inspect"), ("log_scales", 1e30, "all", "prune statistical"),
    ("log_scales", 1e30, "all", "inspect"), ("log_scales", 80.0, "one", "prune statistical"),
    ("log_scales", 80.0, "all", "prune statistical"), ("quats_wxyz", 1e30, "one", "convert"),
    ("quats_wxyz", 1e30, "all", "convert"), ("sh_dc", -1e38, "one", "convert"), ("sh_dc", -1e38, "all", "convert"),
]


def _args(command: str, f: Path, out: Path) -> list:
    return {"prune": ["prune", f, out / "o.ply", "-q"],
            "prune object": ["prune", f, out / "o.ply", "--mode", "object", "-q"],
            "prune statistical": ["prune", f, out / "o.ply", "--mode", "statistical", "-q"],
            "inspect": ["inspect", f, "--histogram", out / "h.png", "-q"],
            "convert": ["convert", f, out / "o.spz"]}[command]


@pytest.mark.parametrize("field,value,which,command", CASES,
                         ids=[f"{f}={v}-{w}-{c}" for f, v, w, c in CASES])
def test_no_numerical_warning_reaches_the_user(field: str, value: float, which: str, command: str, run_cli,
                                                tmp_path: Path) -> None:
    from roodi_toolkit.io.ply import write_ply
    from tests.conftest import make_cloud

    cloud = make_cloud(60, sh_degree=1, seed=2)
    column = getattr(cloud, field)
    if which == "one":
        column[3] = value
    else:
        column[:] = value
    f = write_ply(cloud, tmp_path / "extreme.ply")
    out = tmp_path / "out"
    out.mkdir()
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        res = run_cli(*_args(command, f, out), "--debug")  # --debug: the CLI hides nothing
    assert res.exit_code == 0, res.stderr
    numeric = [f"{w.filename}:{w.lineno}: {w.message}" for w in seen if issubclass(w.category, RuntimeWarning)]
    assert numeric == []
    res = run_cli(*_args(command, f, out), "--overwrite")
    assert res.exit_code == 0 and res.stderr == "", res.stderr


def test_the_cli_hides_numerical_warnings_unless_debug(world, run_cli, monkeypatch) -> None:
    """A numerical warning the sweep did not find still stays off stderr (and is shown with --debug)."""
    import roodi_toolkit.cli.cmd_info as cmd_info

    real = cmd_info.info.callback

    def noisy(*args, **kwargs):
        np.exp(np.float32(1000))  # overflow: a RuntimeWarning
        return real(*args, **kwargs)

    monkeypatch.setattr(cmd_info.info, "callback", noisy)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert run_cli("info", world.ply).exit_code == 0
        assert not [w for w in seen if issubclass(w.category, RuntimeWarning)]
        assert run_cli("info", world.ply, "--debug").exit_code == 0
        assert [w for w in seen if issubclass(w.category, RuntimeWarning)]


@pytest.mark.parametrize("value", [1e38, -1e37, 1e19])
def test_statistical_prune_of_far_centres_is_refused_in_one_line(value: float, run_cli, tmp_path: Path) -> None:
    """The statistical rule's neighbour search (Open3D, float32) cannot measure distances between centres this far
    apart: one line naming the filters that drop them, not Open3D's "Shape [60, 25] is invalid"."""
    from roodi_toolkit.io.ply import write_ply
    from tests.conftest import make_cloud

    from .conftest import expect_failure

    cloud = make_cloud(60, seed=2)
    cloud.means[3] = value
    f = write_ply(cloud, tmp_path / "far.ply")
    res = run_cli("prune", f, tmp_path / "o.ply", "--mode", "statistical", "-q")
    expect_failure(res, 1, "--filter-sphere")
    assert not (tmp_path / "o.ply").exists()
    res = run_cli("prune", f, tmp_path / "o.ply", "--mode", "statistical", "--filter-sphere", "0,0,0,100", "-q")
    assert res.exit_code == 0, res.stderr
