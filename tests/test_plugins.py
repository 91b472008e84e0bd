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
    assert "blur" in res.stdout and "ok" in res.stdout
    assert "bad" in res.stdout and "error: ModuleNotFoundError" in res.stdout
    res = run_cli("plugins", "--json")
    import json

    rows = {r["name"]: r for r in json.loads(res.stdout)}
    assert rows["blur"]["status"] == "ok" and rows["bad"]["status"] == "error"
