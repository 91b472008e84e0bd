import json
import subprocess
import sys

import numpy as np
import pytest
from plyfile import PlyData

from roodi_toolkit import write_ply
from roodi_toolkit.cli.main import COMMANDS, app

from ..conftest import make_cloud
from ..paths import REPO


def test_version_and_help(run_cli):
    from roodi_toolkit import __version__

    res = run_cli("--version")
    assert res.exit_code == 0 and __version__ in res.stdout
    res = run_cli("--help")
    assert res.exit_code == 0
    for name in COMMANDS:
        assert name in res.stdout


def test_the_command_list_reads_as_click_makes_it_and_imports_no_command():
    """``roodi-toolkit --help`` lists each command's short help from its module's source (issue 35: a command's
    module imports what it runs at its top, ``train`` torch): the rows click makes from the imported commands, and
    no command module imported for them."""
    code = ("import sys, click\n"
            "from roodi_toolkit.cli.main import app\n"
            "ctx = click.Context(app, info_name='roodi-toolkit')\n"
            "ours = ctx.make_formatter(); app.format_commands(ctx, ours)\n"
            "print(sorted(m for m in sys.modules if m.startswith('roodi_toolkit.cli.cmd_')))\n"
            "clicks = ctx.make_formatter(); click.Group.format_commands(app, ctx, clicks)\n"
            "print(ours.getvalue() == clicks.getvalue(), len(ours.getvalue().splitlines()))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == ["[]", f"True {len(COMMANDS) + 1}"], out


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_help_shows_an_example(run_cli, name):
    res = run_cli(name, "--help")
    assert res.exit_code == 0, res.stderr
    assert "Example" in res.stdout and f"roodi-toolkit {name}" in res.stdout


def test_usage_errors_exit_2(run_cli):
    assert run_cli("no-such-command").exit_code == 2
    res = run_cli("info")
    assert res.exit_code == 2 and "Missing argument" in res.stderr
    assert run_cli("info", "x.ply", "--bogus").exit_code == 2


def test_info_table_and_json_on_gsplat_style_file(tmp_path, run_cli):
    from ..io.test_ply import reference_columns, write_with_plyfile

    cols = reference_columns(40, 3, seed=2, normals=False)
    cols["x"][:] = np.linspace(-1, 2, 40, dtype=np.float32)
    cols["opacity"][:] = 0.0  # sigmoid(0) = 0.5
    cols["opacity"][:3] = -10.0  # below 1/255
    cols["scale_0"][:] = np.log(0.25)
    cols["scale_1"][:] = np.log(0.5)
    cols["scale_2"][:] = np.log(0.125)
    cols["rot_0"][5] = cols["rot_1"][5] = cols["rot_2"][5] = cols["rot_3"][5] = 0.0
    cols["y"][7] = np.nan
    path = tmp_path / "gs.ply"
    write_with_plyfile(path, cols)
    res = run_cli("info", path, "--json")
    assert res.exit_code == 0, res.stderr
    d = json.loads(res.stdout)
    assert d["count"] == 40 and d["sh_degree"] == 3
    assert d["file"]["variant"] == "gsplat" and d["has_normals"] is False
    assert d["bbox"]["min"][0] == pytest.approx(-1) and d["bbox"]["max"][0] == pytest.approx(2)
    assert d["opacity"]["median"] == pytest.approx(0.5) and d["opacity"]["below_1_255"] == 3
    assert d["scale_max_axis"]["median"] == pytest.approx(0.5) and d["scale_min_axis"]["median"] == pytest.approx(0.125)
    assert d["nonfinite_rows"] == 1 and d["zero_norm_quats"] == 1
    table = run_cli("info", path)
    assert table.exit_code == 0 and "gsplat" in table.stdout and "NaN/Inf rows    1" in table.stdout


def test_debug_shows_traceback_only_when_asked(tmp_path):
    exe = [sys.executable, "-m", "roodi_toolkit.cli.main"]
    res = subprocess.run(exe + ["info", str(tmp_path / "missing.ply")], capture_output=True, text=True)
    assert res.returncode == 1 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    res = subprocess.run(exe + ["info", str(tmp_path / "missing.ply"), "--debug"], capture_output=True, text=True)
    assert res.returncode == 1 and "Traceback" in res.stderr and "PlyError" in res.stderr


def test_console_script_is_installed(tmp_path):
    import shutil

    exe = shutil.which("roodi-toolkit") or str(__import__("pathlib").Path(sys.executable).parent / "roodi-toolkit")
    res = subprocess.run([exe, "--version"], capture_output=True, text=True)
    assert res.returncode == 0 and "roodi-toolkit" in res.stdout


def test_the_source_tree_has_no_top_level_cli_module(tmp_path):
    """From the repository's root (where pytest and a user's `python` put it on sys.path) no top-level module but the
    package, the tests and conftest can be imported, whatever the clone's folder is called."""
    root = REPO
    importable = sorted(p.stem for p in root.iterdir()
                        if p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists()))
    assert importable == ["conftest", "roodi_toolkit", "tests"]
    # a clone named like the project, with the repository root first on sys.path
    code = "import importlib.util, sys; sys.path.insert(0, sys.argv[1]); print(importlib.util.find_spec('cli'))"
    out = subprocess.run([sys.executable, "-c", code, str(root)], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0 and out.stdout.strip() == "None", out.stdout + out.stderr
    assert app.name == "app" and app.callback.__module__ == "roodi_toolkit.cli.main"


def test_the_wheel_installs_only_the_package(tmp_path):
    """The built wheel's top-level entries are the package and its metadata: no `cli`, `tests` or `plugins`."""
    import shutil
    import zipfile

    root = REPO
    src = tmp_path / "roodi-toolkit"  # built from a copy: the build writes build/ and egg-info beside the sources
    shutil.copytree(root / "roodi_toolkit", src / "roodi_toolkit", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("setup.cfg", "pyproject.toml", "README.md"):
        shutil.copy(root / name, src / name)
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                          "--disable-pip-version-check", "-w", str(tmp_path / "dist"), str(src)],
                         capture_output=True, text=True)
    if out.returncode != 0 and "No module named" in out.stderr:
        pytest.skip(f"cannot build a wheel here: {out.stderr.strip().splitlines()[-1]}")
    assert out.returncode == 0, out.stderr
    (wheel,) = (tmp_path / "dist").glob("roodi_toolkit-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        top = {name.split("/")[0] for name in zf.namelist()}
        assert {t for t in top if not t.endswith(".dist-info")} == {"roodi_toolkit"}
        assert any(n.startswith("roodi_toolkit/cli/main.py") for n in zf.namelist())
        (top_level,) = [n for n in zf.namelist() if n.endswith("top_level.txt")] or [None]
        if top_level:
            assert zf.read(top_level).decode().split() == ["roodi_toolkit"]


def test_threads_option_sets_torch_threads(run_cli, monkeypatch, tmp_path):
    import torch

    monkeypatch.setenv("ROODI_THREADS", "1")  # main() writes --threads there; teardown restores the original
    before = torch.get_num_threads()
    try:
        res = run_cli("--threads", "2", "render", tmp_path / "missing.ply", tmp_path / "o")
        assert res.exit_code == 1 and torch.get_num_threads() == 2
        res = run_cli("render", tmp_path / "missing.ply", tmp_path / "o", "--threads=0")
        assert res.exit_code == 1 and "integer from 1 to" in res.stderr and "\n" not in res.stderr.strip()
        # bounded by the machine: 100000 threads segfaulted inside PyTorch
        res = run_cli("--threads", "100000", "render", tmp_path / "missing.ply", tmp_path / "o")
        assert res.exit_code == 1 and "--threads" in res.stderr and "cores" in res.stderr
    finally:
        torch.set_num_threads(before)


def test_sigterm_mid_write_leaves_no_partial_file(tmp_path, run_cli, monkeypatch):
    import os
    import signal

    from roodi_toolkit.io.files import atomic_path

    src = tmp_path / "in.ply"
    write_ply(make_cloud(200, seed=1), src)

    def killed_writer(cloud, path, **kwargs):
        with atomic_path(path) as tmp:
            tmp.write_bytes(b"ply\nhalf")
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr("roodi_toolkit.io.splat.write_ply", killed_writer)  # the name write_cloud calls
    before = signal.getsignal(signal.SIGTERM)
    res = run_cli("prune", src, tmp_path / "out.ply", "-q")
    assert res.exit_code == 143 and "terminated" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply"]  # no output, no hidden temporary file
    assert signal.getsignal(signal.SIGTERM) is before


def test_quiet_and_threads_wherever_they_stand(run_cli, monkeypatch, tmp_path):
    """``-q`` was refused before the command ("No such option '-q'") and on commands without progress bars."""
    import torch

    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud

    monkeypatch.setenv("ROODI_THREADS", "1")
    ply = tmp_path / "in.ply"
    write_ply(planted_floater_cloud(FloaterMix("sphere", n_object=300), 0).cloud, ply)
    loud = run_cli("render", ply, tmp_path / "a", "--orbit", "2", "--size", "16x16")
    assert loud.exit_code == 0 and "orbit up" in loud.stderr
    before = torch.get_num_threads()
    try:
        for n, args in enumerate((("-q", "render", ply, tmp_path / "b"), ("render", "-q", ply, tmp_path / "c"),
                                  ("--threads", "1", "-q", "render", ply, tmp_path / "d", "--threads", "1"))):
            res = run_cli(*args, "--orbit", "2", "--size", "16x16")
            assert res.exit_code == 0, (args, res.stderr)
            assert "orbit up" not in res.stderr and "rendering" not in res.stderr, args
        for args in (("-q", "info", ply), ("info", ply, "-q"), ("--quiet", "plugins"), ("convert", ply,
                     tmp_path / "o.spz", "--quiet"), ("prune", "--threads", "1", ply, tmp_path / "p.ply", "-q")):
            res = run_cli(*args)
            assert res.exit_code == 0, (args, res.stderr)
        res = run_cli("prune", ply, tmp_path / "p2.ply", "--threads", "0")
        assert res.exit_code == 1 and "--threads" in res.stderr  # checked for prune too, which renders late
    finally:
        torch.set_num_threads(before)


HEAVY_LIBRARIES = ("torch", "scipy", "cv2", "open3d", "pyvista", "matplotlib", "kornia", "numba", "PIL")


def test_commands_on_splat_files_import_no_heavy_library(tmp_path):
    """``info``, ``convert`` and ``prune`` of a lone splat file import none of the heavy libraries (issue 35: imports
    at the top of modules must not put torch, 2-5 s, in front of a prune that takes seconds)."""
    src = tmp_path / "in.ply"
    write_ply(make_cloud(300, seed=3), src)
    code = ("import sys; from roodi_toolkit.cli.main import main; "
            f"codes = [main(['info', {str(src)!r}]), main(['convert', {str(src)!r}, {str(tmp_path / 'c.spz')!r}]), "
            f"main(['prune', {str(src)!r}, {str(tmp_path / 'p.ply')!r}, '-q'])]; "
            f"print(codes, sorted(set({HEAVY_LIBRARIES!r}) & {{m.split('.')[0] for m in sys.modules}}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[-1] == "[0, 0, 0] []", out


def test_batch_of_splat_files_imports_no_heavy_library(tmp_path):
    """``batch info``, ``convert`` and ``prune`` of splat files start as light as the single-file commands: only
    ``batch extract`` (its own module, and its own task module) imports the pipeline."""
    (tmp_path / "src").mkdir()
    write_ply(make_cloud(300, seed=3), tmp_path / "src" / "a.ply")
    src = str(tmp_path / "src")
    code = ("import sys; from roodi_toolkit.cli.main import main; "
            f"codes = [main(['batch', 'info', {src!r}, {str(tmp_path / 'i')!r}, '-q']), "
            f"main(['batch', 'convert', {src!r}, {str(tmp_path / 'c')!r}, '--to', '.spz', '-q']), "
            f"main(['batch', 'prune', {src!r}, {str(tmp_path / 'p')!r}, '-q'])]; "
            f"print(codes, sorted(set({HEAVY_LIBRARIES!r}) & {{m.split('.')[0] for m in sys.modules}}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[-1] == "[0, 0, 0] []", out
