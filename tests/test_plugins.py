"""The registry with faked entry points: discovery, lazy loading, a broken plugin, the environment variable."""

import sys
import types
import pytest

from roodi_toolkit import plugins as reg
from roodi_toolkit.errors import PluginError


class FakeDist:
    def __init__(self, name):
        self.metadata = {"Name": name}


def fake_entry_points(mapping):
    def entry_points(group=None):
        eps = []
        return [FakeEntryPoint(name, value, grp, FakeDist(dist))
                for (grp, name), (value, dist) in mapping.items() if grp == group]

    return entry_points


class FakeEntryPoint:
    """What the registry reads of an importlib.metadata.EntryPoint."""

    def __init__(self, name, value, group, dist):
        self.name, self.value, self.group, self.dist = name, value, group, dist


@pytest.fixture
def fake_modules(monkeypatch):
    good = types.ModuleType("fake_good_plugin")

    class Blur:
        name = "blur"

    good.Blur = Blur
    monkeypatch.setitem(sys.modules, "fake_good_plugin", good)
    return good


def test_discover_is_lazy_and_reports_broken_plugins(monkeypatch, fake_modules):
    mapping = {
        ("roodi_toolkit.inpainters", "blur"): ("fake_good_plugin:Blur", "blur-dist"),
        ("roodi_toolkit.inpainters", "broken"): ("module_that_does_not_exist_xyz:Thing", "broken-dist"),
        ("roodi_toolkit.renderers", "badattr"): ("fake_good_plugin:Missing", "other-dist"),
    }
    monkeypatch.setattr(reg.metadata, "entry_points", fake_entry_points(mapping))
    specs = reg.discover("inpainters")
    assert [s.name for s in specs] == ["blur", "broken"]
    assert specs[0].origin == "blur-dist"
    assert reg.load_plugin("inpainters", "blur") is fake_modules.Blur
    with pytest.raises(PluginError, match="'broken'.*broken-dist.*ModuleNotFoundError"):
        reg.load_plugin("inpainters", "broken")
    with pytest.raises(PluginError, match="no inpainter plugin named 'nope'; available: blur, broken"):
        reg.load_plugin("inpainters", "nope")
    statuses = {s.spec.name: s for s in reg.check_all()}
    assert statuses["blur"].ok and not statuses["broken"].ok and not statuses["badattr"].ok
    assert "AttributeError" in statuses["badattr"].error


def test_env_var_registers_and_overrides(monkeypatch, fake_modules):
    monkeypatch.setattr(reg.metadata, "entry_points", fake_entry_points({}))
    monkeypatch.setenv(reg.ENV_VAR, "inpainters:blur=fake_good_plugin:Blur; segmenters:x=nowhere_mod:X")
    assert reg.load_plugin("roodi_toolkit.inpainters", "blur") is fake_modules.Blur
    assert reg.discover("segmenters")[0].origin == "$ROODI_PLUGINS"
    monkeypatch.setenv(reg.ENV_VAR, "garbage;inpainters:blur=fake_good_plugin:Blur")
    # a malformed entry is skipped (it must not break commands that use other plugins) and named where it matters
    assert [s.name for s in reg.discover("inpainters")] == ["blur"]
    with pytest.raises(PluginError, match="cannot parse 'garbage'"):
        reg.load_plugin("inpainters", "missing")
    assert any(not s.ok and "cannot parse 'garbage'" in s.error for s in reg.check_all())


def test_unknown_group():
    with pytest.raises(PluginError, match="unknown plugin group"):
        reg.discover("shaders")


def test_plugins_command_lists_broken_plugin_without_failing(monkeypatch, fake_modules, run_cli):
    monkeypatch.setattr(reg.metadata, "entry_points", fake_entry_points({}))
    monkeypatch.setenv(reg.ENV_VAR, "inpainters:blur=fake_good_plugin:Blur;renderers:bad=missing_mod_q:R")
    res = run_cli("plugins")
    assert res.exit_code == 0
    assert "blur" in res.stdout and "installed" in res.stdout
    assert "bad" in res.stdout and "error: ModuleNotFoundError" in res.stdout
    res = run_cli("plugins", "--json")
    import json

    rows = {r["name"]: r for r in json.loads(res.stdout)}
    assert rows["blur"]["status"] == "installed" and rows["bad"]["status"] == "error"


def test_plugins_say_installed_needs_cuda_weights_or_a_package(monkeypatch, run_cli):
    """``plugins`` listed gsplat (not installed), sdxl (no weights) and sam2 as "ok": a plugin that loads is not one
    that can run. Its class's status() says what it needs; without one, available() says installed or not."""
    mod = types.ModuleType("fake_status_plugins")

    class Ready:
        pass

    class NoGpu:
        @classmethod
        def status(cls):
            return "needs CUDA", "torch sees no GPU"

    class NoWeights:
        @classmethod
        def status(cls):
            return "needs weights", "put them in X"

    class Unavailable:
        @classmethod
        def available(cls):
            return False, "no licence"

    class Crashes:
        @classmethod
        def status(cls):
            raise RuntimeError("boom")

    for cls in (Ready, NoGpu, NoWeights, Unavailable, Crashes):
        setattr(mod, cls.__name__, cls)
    monkeypatch.setitem(sys.modules, "fake_status_plugins", mod)
    monkeypatch.setattr(reg.metadata, "entry_points", fake_entry_points({}))
    monkeypatch.setenv(reg.ENV_VAR, ";".join(f"renderers:{c.lower()}=fake_status_plugins:{c}" for c in (
        "Ready", "NoGpu", "NoWeights", "Unavailable", "Crashes")))
    states = {s.spec.name: (s.state, s.detail) for s in reg.check_all()}
    assert states["ready"] == ("installed", "")
    assert states["nogpu"] == ("needs CUDA", "torch sees no GPU")
    assert states["noweights"] == ("needs weights", "put them in X")
    assert states["unavailable"] == ("unavailable", "no licence")
    assert states["crashes"][0] == "unavailable" and "boom" in states["crashes"][1]
    res = run_cli("plugins")
    assert "needs CUDA: torch sees no GPU" in res.stdout and "needs weights: put them in X" in res.stdout


@pytest.mark.parametrize("plugin, state", [("roodi_gsplat:GsplatRenderer", "needs CUDA"),
                                           ("roodi_sam2:SAM2Segmenter", "needs a package")])
def test_the_bundled_plugins_say_what_they_need(plugin, state):
    module, attr = plugin.split(":")
    cls = getattr(pytest.importorskip(module, reason=f"{module} is not installed"), attr)
    dependency = {"roodi_gsplat": "gsplat", "roodi_sam2": "sam2"}[module]
    import importlib.util

    if importlib.util.find_spec(dependency) is not None:
        pytest.skip(f"{dependency} is installed here")
    got, detail = reg.plugin_state(cls)
    assert got == state and "pip install" in detail
    if module == "roodi_gsplat":  # with a CUDA GPU, only the package is missing
        import torch

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(torch.cuda, "is_available", lambda: True)
            assert reg.plugin_state(cls)[0] == "needs a package"


def test_sdxl_without_weights_needs_weights(monkeypatch, tmp_path):
    roodi_sdxl = pytest.importorskip("roodi_sdxl", reason="the roodi-sdxl plugin is not installed")
    pytest.importorskip("diffusers")
    from roodi_sdxl.inpainter import SDXLInpainter

    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "empty-cache"))
    monkeypatch.setenv("HF_HOME", str(tmp_path / "empty-home"))
    monkeypatch.setenv(roodi_sdxl.inpainter.ENV_MODEL, str(tmp_path / "nothing"))
    state, detail = reg.plugin_state(SDXLInpainter)
    assert state == "needs weights" and "--inpainter-option model=PATH" in detail
    (tmp_path / "nothing").mkdir()
    (tmp_path / "nothing" / "model_index.json").write_text("{}")
    assert reg.plugin_state(SDXLInpainter) == ("installed", "")


PLUGIN_FILE = """
from roodi_toolkit.pipeline.inpaint import Inpainter


class Mean(Inpainter):
    name = "mean"

    def __init__(self, *, strength: float = 1.0, passes: int = 1, blur: bool = False):
        self.strength, self.passes, self.blur = strength, passes, blur

    def fill(self, images, masks, prompt):
        return images
"""


def test_roodi_plugins_works_without_pythonpath_as_documented(tmp_path):
    """docs/plugins.md's no-install route: a module in the current folder, run through a console script (whose
    sys.path starts at its own folder, not the current one): ModuleNotFoundError before. A file path works too."""
    import os
    import subprocess
    from pathlib import Path

    work, bin_dir = tmp_path / "work", tmp_path / "bin"
    work.mkdir()
    bin_dir.mkdir()
    (work / "my_inpainter.py").write_text(PLUGIN_FILE)
    (work / "src").mkdir()
    (work / "src" / "other.py").write_text(PLUGIN_FILE)
    script = bin_dir / "roodi-toolkit"  # what pip's console script does
    script.write_text("import sys\nfrom roodi_toolkit.cli.main import main\nsys.exit(main())\n")
    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(root)  # this source tree as the installed package, nothing of work/
    env["ROODI_PLUGINS"] = "inpainters:mean=my_inpainter:Mean;inpainters:other=src/other.py:Mean"
    out = subprocess.run([sys.executable, str(script), "plugins", "--json"], cwd=work, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    import json

    rows = {r["name"]: r for r in json.loads(out.stdout)}
    assert rows["mean"]["status"] == "installed", rows["mean"]
    assert rows["other"]["status"] == "installed", rows["other"]


def test_plugin_options_from_the_command_line_are_converted(monkeypatch, tmp_path):
    """KEY=VALUE options arrive as text: they take the type of the plugin's default (int, float, bool)."""
    from roodi_toolkit.pipeline.inpaint import Inpainter, get_inpainter

    (tmp_path / "opts_plugin.py").write_text(PLUGIN_FILE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(reg.metadata, "entry_points", fake_entry_points({}))
    monkeypatch.setenv(reg.ENV_VAR, "inpainters:mean=opts_plugin:Mean")
    inp = get_inpainter("mean", strength="0.5", passes="3", blur="yes")
    assert isinstance(inp, Inpainter) and (inp.strength, inp.passes, inp.blur) == (0.5, 3, True)
    with pytest.raises(PluginError, match=r"option passes='many': expected int"):
        get_inpainter("mean", passes="many")
    with pytest.raises(PluginError, match="does not take these options"):
        get_inpainter("mean", colour="red")


def test_every_plugin_kind_takes_its_options_from_the_command_line(monkeypatch, run_cli, tmp_path):
    """extract had --segmenter-option but no inpainter option, and no command took renderer options."""
    from roodi_toolkit.render.renderer import TorchRenderer
    import roodi_toolkit.cli.cmd_extract as extract_command

    seen = {}

    class Tiled(TorchRenderer):
        def __init__(self, *, tile: int = 16):
            super().__init__()
            seen["tile"] = tile

    mod = types.ModuleType("fake_option_plugins")
    mod.Tiled = Tiled
    (tmp_path / "opts_inpainter.py").write_text(PLUGIN_FILE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(sys.modules, "fake_option_plugins", mod)
    monkeypatch.setenv(reg.ENV_VAR, "renderers:tiled=fake_option_plugins:Tiled;inpainters:mean=opts_inpainter:Mean")
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud

    write_ply(planted_floater_cloud(FloaterMix("sphere", n_object=200), 0).cloud, tmp_path / "in.ply")
    res = run_cli("render", tmp_path / "in.ply", tmp_path / "r", "--orbit", "1", "--size", "8x8",
                  "--renderer", "tiled", "--renderer-option", "tile=8", "-q")
    assert res.exit_code == 0, res.stderr
    assert seen["tile"] == 8
    res = run_cli("render", tmp_path / "in.ply", tmp_path / "r2", "--orbit", "1", "--renderer-option", "nope=1")
    assert res.exit_code == 1 and "does not take these options" in res.stderr

    captured = {}

    def fake_extract(data_dir, out_dir, object_ids, **kwargs):
        captured.update(kwargs)
        return {"reused": [], "recomputed": [], "objects": {}}

    monkeypatch.setattr(extract_command, "extract_objects", fake_extract)  # the name the command calls
    res = run_cli("extract", tmp_path, tmp_path / "o", "--object", "1", "--inpainter", "mean",
                  "--inpainter-option", "strength=0.25", "--inpainter-option", "passes=2")
    assert res.exit_code == 0, res.stderr
    assert captured["config"].inpainter_options == {"strength": "0.25", "passes": "2"}
    res = run_cli("extract", tmp_path, tmp_path / "o", "--object", "1", "--inpainter", "mean",
                  "--inpainter-option", "passes=many")
    assert res.exit_code == 1 and "passes='many': expected int" in res.stderr  # refused before any training
    res = run_cli("extract", tmp_path, tmp_path / "o", "--object", "1", "--inpainter-option", "novalue")
    assert res.exit_code == 2 and "--inpainter-option" in res.stderr
