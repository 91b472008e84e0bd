"""Options made from config dataclasses (roodi_toolkit.cli.settings): every prune setting is an option of the
commands that prune, with its field's default, range and help; every pruning option maps back to a field; a parsed
command line round-trips to the config. A new setting is one field: its option follows."""

from __future__ import annotations

import json
from dataclasses import dataclass, fields

import click
import pytest
from click.testing import CliRunner

from roodi_toolkit.cli.settings import (SettingsCommand, click_type, command_settings, config_from_options,
                                       config_options, option_names)
from roodi_toolkit.errors import ConfigError
from roodi_toolkit.pipeline.finetune import FinetuneConfig
from roodi_toolkit.prune.config import PhotoSettings, PruneConfig
from roodi_toolkit.render.settings import OrbitSettings
from roodi_toolkit.settings import declared, setting
from roodi_toolkit.viz.inspect import InspectView

# command -> (the config classes its options are made from, its own parameters that are no setting of them)
OWN = {
    "prune": ((PruneConfig, PhotoSettings),
              {"input_ply", "output_ply", "dry_run", "up", "floaters_out", "report_path", "overwrite", "quiet"}),
    "inspect": ((PruneConfig, PhotoSettings, InspectView),
                {"input_ply", "window_size", "screenshot", "view_png", "html_path", "histogram", "up", "window",
                 "overwrite", "quiet"}),
    "batch prune": ((PruneConfig,), {"source", "out", "jobs", "ray_address", "results", "rerun", "overwrite",
                                     "quiet"}),
    "render": ((OrbitSettings,), {"ply", "out_dir", "cameras_path", "up", "frame_like", "size_text", "what",
                                  "background", "renderer_option", "renderer", "filter_nan", "overwrite",
                                  "quiet"}),
}


def _command(name: str) -> click.Command:
    from roodi_toolkit.cli.main import app

    ctx = click.Context(app)
    cmd = app.get_command(ctx, name.split()[0])
    return cmd.get_command(ctx, name.split()[1]) if " " in name else cmd


@pytest.mark.parametrize("name", sorted(OWN))
def test_every_setting_is_an_option_and_every_option_a_setting(name):
    cmd = _command(name)
    classes, own = OWN[name]
    settings = {d.name: d for d in command_settings(*classes)}
    params = {p.name: p for p in cmd.params}
    assert set(params) - own == set(settings)  # each option of the command is a setting, each setting offered
    for d in settings.values():
        p = params[d.name]
        assert p.opts == [d.option] and p.help == d.meta.help
        assert p.default == d.default and p.is_flag == (d.kind is bool) and p.multiple == d.repeated
        assert bool(p.show_default) == (d.default not in (None, False, ()))
        if d.meta.choices is not None:
            assert tuple(p.type.choices) == d.meta.choices


def test_library_only_settings_are_no_options():
    assert {d.name for d in declared(PruneConfig) if not d.meta.cli} == {"max_iterations", "compute_dtype",
                                                                         "object_fraction", "fog_tolerance"}


def test_help_shows_defaults_and_ranges_of_the_fields(run_cli):
    res = run_cli("prune", "--help")
    text = " ".join(res.stdout.split())
    for expected in ("--k INTEGER RANGE Neighbours per Gaussian, not counting itself. [default: 16; x>=1]",
                     "--photo-views INTEGER RANGE", "[default: 32; x>=1]", "--max-piece INTEGER RANGE",
                     "--distance [w2|euclidean]", "--filter-box X0,Y0,Z0,X1,Y1,Z1 Keep only", "[default: 0.12]"):
        assert expected in text, expected


def test_a_parsed_command_line_round_trips_to_the_config():
    cmd = _command("prune")
    args = ["in.ply", "out.ply", "--k", "7", "--alpha", "2.5", "--distance", "w2", "--rule", "clip", "--neighbors",
            "w2", "--filter-nan", "--min-opacity", "0.01", "--filter-box", "-1,-2,-3, 1,2,3", "--filter-sphere",
            "0,0,0,5", "--filter-value", "z,-1,1", "--filter-value", "scale,0,0.5", "--mode", "object", "--reach",
            "2", "--min-cluster", "0.01", "--max-piece", "0", "--blob-score", "0.7", "--blob-colour", "0",
            "--blob-sure", "3", "--foreign-size", "0", "--background", "white", "--photos", "none",
            "--photo-views", "4"]
    values = cmd.make_context("prune", args).params
    config = config_from_options(PruneConfig, values)
    assert config == PruneConfig(k=7, alpha=2.5, distance="w2", rule="clip", neighbors="w2", filter_nan=True,
                                 min_opacity=0.01, box=(-1.0, -2.0, -3.0, 1.0, 2.0, 3.0), sphere=(0.0, 0.0, 0.0, 5.0),
                                 value_ranges=(("z", -1.0, 1.0), ("scale", 0.0, 0.5)), mode="object", reach=2.0,
                                 min_cluster=0.01, max_piece=0, blob_score=0.7, blob_colour=0.0, blob_sure=3.0,
                                 foreign_size=0.0, background="white")
    assert config_from_options(PhotoSettings, values) == PhotoSettings(photos="none", photo_views=4)
    # every setting above differs from its default: the round trip proves each option reaches its field
    default = PruneConfig()
    assert [f.name for f in fields(PruneConfig) if getattr(config, f.name) == getattr(default, f.name)] == \
        [name for name in ("distance", "max_iterations", "compute_dtype", "object_fraction", "fog_tolerance")]
    # no option given: the config's defaults
    assert config_from_options(PruneConfig, cmd.make_context("prune", ["a", "b"]).params) == PruneConfig()


def test_render_orbit_options_round_trip_to_the_orbit_settings():
    values = _command("render").make_context("render", ["in.ply", "out", "--orbit", "3", "--elevation", "-10",
                                                        "--radius", "2.5", "--fov", "90"]).params
    orbit = config_from_options(OrbitSettings, values)
    assert orbit == OrbitSettings(orbit=3, elevation=-10.0, radius=2.5, fov=90.0) and orbit.views == 3
    assert config_from_options(OrbitSettings, _command("render").make_context("render", ["a", "b"]).params).views == 8


def test_inspect_view_options_round_trip_to_the_view():
    args = ["in.ply", "--show", "removed", "--color-by", "distance", "--highlight", "none", "--glyphs", "splats",
            "--camera", "+z"]
    values = _command("inspect").make_context("inspect", args).params
    assert config_from_options(InspectView, values) == InspectView(show="removed", color_by="distance",
                                                                   highlight="none", glyphs="splats", camera="+z")


@pytest.mark.parametrize("args,code,needle", [
    (["--filter-box", "1,2,3"], 2, "--filter-box"),
    (["--filter-value", "size,0,1"], 2, "--filter-value"),
    (["--filter-value", "z,1,0"], 2, "MIN must not exceed MAX"),
    (["--filter-box", "1,1,1,0,0,0"], 1, "box must be x0,y0,z0,x1,y1,z1"),
    (["--foreign-size", "0.5"], 1, "foreign_size must be 0 (off)"),
    (["--neighbors", "w2", "--distance", "euclidean"], 1, "neighbors 'w2' needs distance 'w2'"),
])
def test_bad_values_are_refused_naming_the_option_or_setting(run_cli, tmp_path, args, code, needle):
    res = run_cli("prune", tmp_path / "missing.ply", tmp_path / "o.ply", *args)
    assert res.exit_code == code and needle in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


@dataclass(frozen=True)
class Extended(PruneConfig):
    """PruneConfig with one more setting, as a contributor would add it."""

    knob: float = setting(0.25, "Turn the knob.", low=0, high=1)


@dataclass(frozen=True)
class ExtendedFinetune(FinetuneConfig):
    """FinetuneConfig with one more command-line setting, as a contributor would add it."""

    passes: int = setting(1, "Extra passes.", low=1)


def test_a_new_setting_is_one_field_its_option_follows():
    @click.command()
    @config_options(Extended)
    def cmd(**values):
        click.echo(repr(config_from_options(Extended, values)))

    param = next(p for p in cmd.params if p.name == "knob")
    assert param.opts == ["--knob"] and param.default == 0.25 and param.help == "Turn the knob."
    assert isinstance(click_type(declared(Extended)[-1]), click.FloatRange)
    assert option_names(Extended) == (*option_names(PruneConfig), "knob")
    from click.testing import CliRunner

    out = CliRunner().invoke(cmd, ["--knob", "0.5", "--k", "9"])
    assert out.exit_code == 0 and out.output.strip() == repr(Extended(knob=0.5, k=9))
    assert CliRunner().invoke(cmd, ["--knob", "2"]).exit_code == 2  # its range, from the field
    assert "[default: 0.25; 0<=x<=1]" in " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())


def test_statistical_options_imply_the_statistical_mode(run_cli, tmp_path):
    """``--mode auto`` with an option of StatisticalSettings runs the statistical rule; --k (both rules) does not."""
    from roodi_toolkit.io.ply import write_ply
    from tests.conftest import make_cloud

    src = write_ply(make_cloud(300, seed=1), tmp_path / "c.ply")
    for extra, mode in ((["--alpha", "3"], "statistical"), (["--neighbors", "centre"], "statistical"),
                        (["--k", "8"], "auto")):
        res = run_cli("prune", src, tmp_path / "o.ply", "--report", tmp_path / "r.json", "--overwrite", "-q", *extra)
        assert res.exit_code == 0, res.stderr
        report = json.loads((tmp_path / "r.json").read_text())
        assert (report["mode"] == "statistical") == (mode == "statistical"), (extra, report["mode"])


# ------------------------------------------------------------------ nested configs, negated flags, unset options
@dataclass(frozen=True)
class Inner:
    steps: int = setting(5, "Inner steps.", low=1)
    rate: float = setting(0.5, "Inner rate.", low=0)
    secret: int = setting(2, "Library only.", cli=False)


@dataclass(frozen=True)
class Outer:
    on: bool = setting(True, "Do the thing; --no-on skips it.")
    inner: Inner = setting(factory=lambda: Inner(steps=9), help="The inner stage.", prefix="inner")
    flat: Inner = setting(factory=Inner, help="Another stage, its options unprefixed.", prefix="")
    notes: dict = setting(factory=dict, help="Library only.", cli=False)


def _toy(options):
    @click.command(cls=SettingsCommand)
    @options
    def cmd(**values):
        click.echo(repr(options.config(values)))

    return cmd


def test_nested_configs_get_prefixed_options_with_the_base_configs_defaults():
    from roodi_toolkit.cli.settings import Options

    opts = Options(Outer)
    got = [(o.option, o.param, o.path, o.default) for o in opts.offered()]
    assert got == [("--no-on", "on", ("on",), True), ("--inner-steps", "inner_steps", ("inner", "steps"), 9),
                   ("--inner-rate", "inner_rate", ("inner", "rate"), 0.5), ("--steps", "steps", ("flat", "steps"), 5),
                   ("--rate", "rate", ("flat", "rate"), 0.5)]
    from click.testing import CliRunner

    out = CliRunner().invoke(_toy(opts), ["--inner-steps", "3", "--no-on", "--rate", "2"])
    assert out.exit_code == 0, out.output
    assert out.output.strip() == repr(Outer(on=False, inner=Inner(steps=3), flat=Inner(rate=2.0)))
    assert CliRunner().invoke(_toy(opts), []).output.strip() == repr(Outer())
    assert CliRunner().invoke(_toy(opts), ["--inner-steps", "0"]).exit_code == 2  # the nested field's range
    text = " ".join(CliRunner().invoke(_toy(opts), ["--help"]).output.split())
    assert "--inner-steps INTEGER RANGE Inner steps. [default: 9; x>=1]" in text  # the base's 9, not the field's 5
    assert "--no-on Do the thing; --no-on skips it." in text and "secret" not in text


def test_only_picks_settings_in_its_order_and_refuses_unknown_names():
    from roodi_toolkit.cli.settings import Options

    opts = Options(Outer, only=("flat.rate", "inner.steps"))
    assert [o.option for o in opts.offered()] == ["--rate", "--inner-steps"]
    assert opts.config({"rate": 1.0, "inner_steps": 4}) == Outer(inner=Inner(steps=4), flat=Inner(rate=1.0))
    with pytest.raises(TypeError, match="no command-line setting inner.secret"):
        Options(Outer, only=("inner.secret",)).offered()


def test_unset_options_keep_the_base_value_and_show_it_as_default():
    from click.testing import CliRunner

    from roodi_toolkit.cli.settings import Options

    opts = Options(Outer, unset=True, only=("on", "inner.steps", "flat.rate"))
    cmd = _toy(opts)
    values = cmd.make_context("cmd", []).params
    assert values == {"on": None, "inner_steps": None, "rate": None}
    resumed = Outer(on=False, inner=Inner(steps=40), flat=Inner(rate=3.0))
    assert opts.config(values, base=resumed) == resumed  # nothing given: the resumed run's values
    given = cmd.make_context("cmd", ["--inner-steps", "7"]).params
    assert opts.config(given, base=resumed) == Outer(on=False, inner=Inner(steps=7), flat=Inner(rate=3.0))
    assert opts.config(cmd.make_context("cmd", ["--no-on"]).params) == Outer(on=False)
    text = " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())
    assert "Inner steps. [default: 9; x>=1]" in text and "Inner rate. [default: 0.5; x>=0]" in text


def test_options_named_by_text_are_made_when_the_command_is_used():
    """``roodi-toolkit --help`` lists the commands without making their options: their configs' modules import
    PyTorch. The made options get the CLI's finite floats."""
    from roodi_toolkit.cli.main import FiniteFloat, _finite_floats
    from roodi_toolkit.cli.settings import Options

    cmd = _finite_floats(_toy(Options("tests.cli.test_settings:Outer", only=("inner.rate",))))
    assert cmd.made_params == []
    (param,) = cmd.params
    assert param.name == "inner_rate" and isinstance(param.type, FiniteFloat)


def test_listing_the_commands_imports_no_pytorch():
    import subprocess
    import sys

    code = ("import sys; from roodi_toolkit.cli.main import main\ntry: main(['--help'])\nexcept SystemExit: pass\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split()[-1] == "False", out


# ------------------------------------------------------------------ the pipeline commands' options
def _settings_of(name):
    """The Options a pipeline command's settings are made from, and its own parameters that are no setting."""
    from roodi_toolkit.cli import cmd_distill, cmd_extract, cmd_select, cmd_train

    extract_own = {"model_dir", "distill_dir", "inpainter_options", "quiet"}
    run = {"overwrite", "renderer", "renderer_option", "quiet"}  # renderer_option: --renderer-option's parameter
    return {
        "train": (cmd_train.TRAIN_SETTINGS, run | {"data_dir", "out_dir", "downscale", "resume"}),
        "distill": (cmd_distill.DISTILL_SETTINGS, run | {"model_dir", "data_dir", "out_dir", "segmenter", "clicks",
                                                         "negative_clicks", "mask_dir", "options", "downscale",
                                                         "dataparser_transforms"}),
        "select": (cmd_select.SELECT_SETTINGS, run | {"distill_dir", "output_ply", "object_id", "picture"}),
        "extract": (cmd_extract.EXTRACT_SETTINGS, run | extract_own | {
            "paths", "object_ids", "clicks", "negative_clicks", "view", "segmenter", "segmenter_options", "mask_dir",
            "dataparser_transforms"}),
        "batch extract": (cmd_extract.EXTRACT_SETTINGS, extract_own | {"data_dir", "out", "object_ids", "jobs",
                                                                       "ray_address", "results", "rerun"}),
    }[name]


@pytest.mark.parametrize("name", ["train", "distill", "select", "extract", "batch extract"])
def test_pipeline_options_are_the_configs_settings(name):
    """Each option of the pipeline commands is a setting of their config (help, range, default from its field),
    or one of the command's own parameters."""
    options, own = _settings_of(name)
    params = {p.name: p for p in _command(name).params}
    offered = {o.param: o for o in options.offered()}
    assert set(params) - own == set(offered)
    for o in offered.values():
        p = params[o.param]
        assert [*p.opts, *p.secondary_opts] == o.option.split("/") and p.help == o.setting.meta.help
        assert p.default == (None if options.unset else o.default)
        if o.setting.meta.choices is not None:
            assert tuple(p.type.choices) == o.setting.meta.choices


def test_train_options_round_trip_to_the_train_config():
    from roodi_toolkit.cli.cmd_train import TRAIN_SETTINGS
    from roodi_toolkit.pipeline.strategy import MCMCStrategy
    from roodi_toolkit.pipeline.train import TrainConfig

    cmd = _command("train")
    args = ["d", "o", "--iterations", "7", "--cap-max", "900", "--sh-degree", "1", "--init", "random",
            "--init-points", "50", "--fixed-background", "--eval-every", "0", "--checkpoint-every", "3", "--seed", "4"]
    config = TRAIN_SETTINGS.config(cmd.make_context("train", args).params)
    assert config == TrainConfig(iterations=7, strategy=MCMCStrategy(cap_max=900), sh_degree=1, init="random",
                                 init_num_points=50, random_background=False, eval_every=0, checkpoint_every=3,
                                 seed=4)
    # none given: every option None (a resumed run keeps its own), the config TrainConfig's defaults
    values = cmd.make_context("train", ["d", "o"]).params
    assert [values[o.param] for o in TRAIN_SETTINGS.offered()] == [None] * 9
    assert TRAIN_SETTINGS.config(values) == TrainConfig() and TrainConfig().strategy.cap_max == 60_000
    assert TRAIN_SETTINGS.config(cmd.make_context("train", ["d", "o", "--random-background"]).params) == \
        TrainConfig(random_background=True)
    for bad in (["--init-points", "3"], ["--sh-degree", "4"], ["--init", "sfm"], ["--seed", "-1"]):
        assert CliRunner().invoke(cmd, ["d", "o", *bad]).exit_code == 2, bad


def test_distill_and_select_options_round_trip():
    from roodi_toolkit.cli.cmd_distill import DISTILL_SETTINGS
    from roodi_toolkit.pipeline.distill import DistillConfig

    values = _command("distill").make_context("distill", ["m", "d", "o", "--iterations", "9", "--feature-lr", "0.1",
                                                          "--classifier-lr", "0.2", "--seed", "3"]).params
    assert DISTILL_SETTINGS.config(values) == DistillConfig(iterations=9, feature_lr=0.1, classifier_lr=0.2, seed=3)
    assert DISTILL_SETTINGS.config(_command("distill").make_context("distill", ["m", "d", "o"]).params) == \
        DistillConfig()
    select = _command("select")
    assert {k: select.make_context("select", ["d", "o.ply", "--object", "1", *extra]).params[k]
            for extra, k in ((["--threshold", "0.6"], "threshold"), ([], "prune"))} == {"threshold": 0.6,
                                                                                        "prune": True}
    assert select.make_context("select", ["d", "o.ply", "--object", "1", "--no-prune"]).params["prune"] is False


@pytest.mark.parametrize("name", ["extract", "batch extract"])
def test_extract_options_round_trip_to_the_extract_config(name):
    from dataclasses import replace

    from roodi_toolkit.cli.cmd_extract import extract_config_from_options
    from roodi_toolkit.pipeline.distill import DistillConfig
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.prune.config import PruneConfig

    cmd = _command(name)
    paths = ["d", "o", "--object", "1"]
    args = [*paths, "--downscale", "2", "--iterations", "50", "--init", "random", "--distill-iterations", "20",
            "--threshold", "0.5", "--no-prune", "--no-inpaint", "--distance", "euclidean", "--rule", "paper",
            "--single-stage", "--inpainter", "exemplar", "--inpainter-option", "patch=5"]
    values = cmd.make_context(name, args).params
    base = ExtractConfig()
    assert extract_config_from_options(**values) == replace(
        base, downscale=2.0, train=replace(base.train, iterations=50, init="random"),
        distill=DistillConfig(iterations=20), threshold=0.5, prune=False, inpaint=False,
        prune_config=PruneConfig(distance="euclidean", rule="paper"), single_stage=True, inpainter="exemplar",
        inpainter_options={"patch": "5"})
    assert extract_config_from_options(**cmd.make_context(name, paths).params) == base


def test_demo_settings_default_to_the_demos_own_config():
    """The demo's --iterations, --distill-iterations and --inpainter are its ExtractConfig's settings: unset they keep
    the demo's values (2000 steps, symmetry), and given they are still refused with --prune-only."""
    from dataclasses import replace

    from roodi_toolkit.cli.cmd_demo import DEMO_SETTINGS
    from roodi_toolkit.synth.demo import ExtractDemoConfig

    base = ExtractDemoConfig().extract
    cmd = _command("demo")
    assert DEMO_SETTINGS.config(cmd.make_context("demo", ["out"]).params, base=base) == base
    assert (base.train.iterations, base.inpainter) == (2000, "symmetry")
    values = cmd.make_context("demo", ["out", "--iterations", "30", "--distill-iterations", "7", "--inpainter",
                                       "opencv"]).params
    assert DEMO_SETTINGS.config(values, base=base) == replace(
        base, train=replace(base.train, iterations=30), distill=replace(base.distill, iterations=7),
        inpainter="opencv")
    text = " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())
    assert "[default: 2000; x>=1]" in text and "[default: symmetry]" in text
    res = CliRunner().invoke(cmd, ["out", "--prune-only", "--distill-iterations", "3", "--inpainter", "x"])
    assert res.exit_code == 2 and "--distill-iterations, --inpainter: options of the extraction demo" in res.output


def test_demo_refinement_options_are_the_finetune_and_occlusion_settings():
    """--finetune-iterations and --view-size are FinetuneConfig.iterations and OcclusionConfig.size (ranges, help
    and the demo's defaults from the fields); unset they keep the demo's values, and --prune-only refuses them."""
    from dataclasses import replace

    from roodi_toolkit.cli.cmd_demo import DEMO_REFINE_SETTINGS, DEMO_SETTINGS
    from roodi_toolkit.pipeline.finetune import FinetuneConfig
    from roodi_toolkit.pipeline.occlusion import OcclusionConfig
    from roodi_toolkit.settings import declared

    base = _demo_extract()
    cmd = _command("demo")
    offered = {o.param: o for o in DEMO_REFINE_SETTINGS.offered()}
    assert [o.option for o in offered.values()] == ["--finetune-iterations", "--view-size"]
    assert offered["finetune_iterations"].setting == declared(FinetuneConfig)[0]
    assert offered["size"].setting == next(d for d in declared(OcclusionConfig) if d.name == "size")
    params = {p.name: p for p in cmd.params}
    assert params["finetune_iterations"].help == "Fine-tuning steps." and params["size"].opts == ["--view-size"]
    values = cmd.make_context("demo", ["out", "--finetune-iterations", "0", "--view-size", "64", "--iterations",
                                       "5"]).params
    config = DEMO_REFINE_SETTINGS.config(values, base=DEMO_SETTINGS.config(values, base=base))
    assert config == replace(base, train=replace(base.train, iterations=5), finetune=FinetuneConfig(iterations=0),
                             occlusion=OcclusionConfig(size=64))
    none = cmd.make_context("demo", ["out"]).params
    assert DEMO_REFINE_SETTINGS.config(none, base=base) == base and (base.finetune.iterations,
                                                                     base.occlusion.size) == (100, 256)
    for bad in (["--view-size", "7"], ["--view-size", "4097"], ["--finetune-iterations", "-1"]):
        assert CliRunner().invoke(cmd, ["out", *bad]).exit_code == 2, bad
    text = " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())
    assert "--finetune-iterations INTEGER RANGE Fine-tuning steps. [default: 100; x>=0]" in text
    assert "inpainted. [default: 256; 8<=x<=4096]" in text
    res = CliRunner().invoke(cmd, ["out", "--prune-only", "--view-size", "64", "--max-gaussians", "9"])
    assert res.exit_code == 2 and "--max-gaussians, --view-size: options of the extraction demo" in res.output


def _demo_extract():
    """The ExtractConfig of the extraction demo (its defaults are the demo's own)."""
    from roodi_toolkit.synth.demo import ExtractDemoConfig

    return ExtractDemoConfig().extract


def _extended_extract():
    """An ExtractConfig whose fine-tuning has one more setting (the target of an Options named by text)."""
    from roodi_toolkit.pipeline.extract import ExtractConfig

    return ExtractConfig(finetune=ExtendedFinetune())


def test_a_new_finetune_setting_is_one_field_its_options_follow():
    """A FinetuneConfig with one more field: its option (and range, help) follows, alone and as a setting of
    ExtractConfig's fine-tuning (``--finetune-`` prefix), with no other edit."""
    from roodi_toolkit.cli.settings import Options

    @click.command()
    @config_options(ExtendedFinetune)
    def alone(**values):
        click.echo(repr(config_from_options(ExtendedFinetune, values)))

    assert [p.opts for p in alone.params] == [["--iterations"], ["--passes"]]
    out = CliRunner().invoke(alone, ["--passes", "3", "--iterations", "7"])
    assert out.exit_code == 0 and out.output.strip() == repr(ExtendedFinetune(passes=3, iterations=7))
    assert CliRunner().invoke(alone, ["--passes", "0"]).exit_code == 2

    nested = Options("tests.cli.test_settings:_extended_extract", only=("finetune.iterations", "finetune.passes"))
    cmd = _toy(nested)
    assert [(p.opts, p.name) for p in cmd.params] == [(["--finetune-iterations"], "finetune_iterations"),
                                                       (["--finetune-passes"], "finetune_passes")]
    out = CliRunner().invoke(cmd, ["--finetune-passes", "4"])
    assert out.exit_code == 0, out.output
    assert out.output.strip() == repr(_extended_extract().__class__(finetune=ExtendedFinetune(passes=4)))
    assert "Extra passes. [default: 1; x>=1]" in " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())
    with pytest.raises(ConfigError, match="passes must be a whole number >= 1"):
        ExtendedFinetune(passes=0)


def test_two_settings_that_would_be_one_parameter_are_refused():
    from roodi_toolkit.cli.settings import Options

    @dataclass(frozen=True)
    class Twice:
        inner: Inner = setting(factory=Inner, help="One stage.", prefix="")
        again: Inner = setting(factory=Inner, help="Another, also unprefixed.", prefix="")

    with pytest.raises(TypeError, match="inner.steps and again.steps would both be the parameter 'steps'"):
        Options(Twice, only=("inner.rate",)).offered()


def test_benchmark_size_options_are_the_benchmark_sizes_settings():
    """--size and --iterations are BenchmarkSize's fields (help and range from them); unset they keep the --scale's
    size, given they change it, and --help shows no default (it is the --scale's)."""
    from dataclasses import replace

    from roodi_toolkit.cli.cmd_benchmark import SIZE_SETTINGS
    from roodi_toolkit.evaluate.benchmark import MACHINE_SIZE, PAPER_SIZE, SIZES, BenchmarkSize

    cmd = _command("benchmark")
    assert [o.option for o in SIZE_SETTINGS.offered()] == ["--size", "--iterations"]
    params = {p.name: p for p in cmd.params}
    assert params["size"].help == "Image size of the generated scenes." and params["size"].default is None
    assert (params["size"].type.min, params["size"].type.max, params["iterations"].type.min) == (16, 2048, 1)
    assert BenchmarkSize() == MACHINE_SIZE
    values = cmd.make_context("benchmark", ["r", "o", "--scale", "paper", "--size", "32"]).params
    assert SIZE_SETTINGS.config(values, base=SIZES[values["scale"]]) == replace(PAPER_SIZE, size=32)
    values = cmd.make_context("benchmark", ["r", "o", "--iterations", "7"]).params
    assert SIZE_SETTINGS.config(values, base=SIZES[values["scale"]]) == replace(MACHINE_SIZE, iterations=7)
    for bad in (["--size", "15"], ["--size", "2049"], ["--iterations", "0"]):
        assert CliRunner().invoke(cmd, ["r", "o", *bad]).exit_code == 2, bad
    text = " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())
    assert "--size INTEGER RANGE Image size of the generated scenes. [16<=x<=2048]" in text
    assert "--iterations INTEGER RANGE Scene training iterations. [x>=1]" in text


def test_unset_flags_show_no_default():
    from roodi_toolkit.cli.settings import Options

    text = " ".join(CliRunner().invoke(_toy(Options(Outer, unset=True, only=("on",))), ["--help"]).output.split())
    assert "--no-on Do the thing; --no-on skips it." in text and "default" not in text


# ------------------------------------------------------------------ the generated scene's settings (make-scene, demo)
MAKE_SCENE_OWN = {"out_dir", "preset", "seed", "overwrite", "quiet"}


def test_make_scene_options_are_the_scene_settings():
    """Every option of make-scene but its own is a command-line setting of SceneSettings (help, range, default from
    the field); --size is width's option and sets height too; a full command line round-trips to the settings."""
    from roodi_toolkit.synth.scene import SceneSettings

    cmd = _command("make-scene")
    settings = {d.name: d for d in command_settings(SceneSettings)}
    params = {p.name: p for p in cmd.params}
    assert set(params) - MAKE_SCENE_OWN == set(settings) == {
        "width", "train_views", "test_views", "supersample", "n_targets", "n_objects", "test_framing", "occluded",
        "never_seen"}
    for d in settings.values():
        assert params[d.name].opts == [d.option] and params[d.name].help == d.meta.help
    assert [params[n].opts[0] for n in ("width", "n_objects", "n_targets")] == ["--size", "--objects", "--targets"]
    args = ["out", "--size", "64x48", "--train-views", "3", "--test-views", "2", "--objects", "6", "--targets", "2",
            "--supersample", "1", "--test-framing", "object", "--occluded", "--never-seen"]
    values = cmd.make_context("make-scene", args).params
    want = SceneSettings(width=64, height=48, train_views=3, test_views=2, n_objects=6, n_targets=2, supersample=1,
                         test_framing="object", occluded=True, never_seen=True)
    assert config_from_options(SceneSettings, values) == want
    assert [f.name for f in fields(SceneSettings) if getattr(want, f.name) == getattr(SceneSettings(), f.name)] == \
        ["fov_x_deg"]  # every other field differs from its default: each option reached its field
    assert config_from_options(SceneSettings, cmd.make_context("make-scene", ["out"]).params) == SceneSettings()
    assert config_from_options(SceneSettings, cmd.make_context("make-scene", ["o", "--size", "40"]).params) == \
        SceneSettings(width=40, height=40)
    text = " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())
    assert "--size TEXT Image size WIDTHxHEIGHT (or one number). [default: 200x200]" in text
    assert "--train-views INTEGER RANGE Views of the full scene. [default: 50; 1<=x<=1000]" in text


@pytest.mark.parametrize("args,needle", [
    (["--size", "4"], "Invalid value for '--size': size must be between 8 and 8192 pixels, got '4'"),
    (["--size", "8x9000"], "Invalid value for '--size': size must be between 8 and 8192 pixels"),
    (["--size", "wide"], "Invalid value for '--size': expected WIDTHxHEIGHT"),
    (["--train-views", "1001"], "'--train-views'"),
    (["--objects", "21"], "'--objects'"),
    (["--targets", "0"], "'--targets'"),
    (["--supersample", "5"], "'--supersample'"),
    (["--test-framing", "far"], "'--test-framing'"),
])
def test_make_scene_refuses_values_outside_the_settings_naming_the_option(run_cli, tmp_path, args, needle):
    res = run_cli("make-scene", tmp_path / "s", *args, "-q")
    assert res.exit_code == 2 and needle in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "s").exists()


def _extended_scene_class():
    """SceneSettings with one more setting, as a contributor would add it."""
    from roodi_toolkit.synth.scene import SceneSettings

    @dataclass(frozen=True)
    class Extended(SceneSettings):
        haze: float = setting(0.0, "Haze density.", low=0, high=1)

    return Extended


def test_a_new_scene_setting_is_one_field_its_option_follows():
    from roodi_toolkit.cli.settings import Options

    extended = _extended_scene_class()
    options = Options(extended)
    cmd = _toy(options)
    assert [p.opts[0] for p in cmd.params][-1] == "--haze"
    param = next(p for p in cmd.params if p.name == "haze")
    assert param.default == 0.0 and param.help == "Haze density." and isinstance(param.type, click.FloatRange)
    out = CliRunner().invoke(cmd, ["--haze", "0.5", "--size", "30x20"])
    assert out.exit_code == 0, out.output
    assert out.output.strip() == repr(extended(haze=0.5, width=30, height=20))
    assert CliRunner().invoke(cmd, ["--haze", "2"]).exit_code == 2  # its range, from the field
    with pytest.raises(ConfigError, match="haze must be a finite number in"):
        extended(haze=-1.0)


def test_demo_scene_options_are_the_scene_settings_with_the_demos_defaults():
    """The demo's --preset, --object, --size, --train-views, --test-views and --occluded/--no-occluded are settings of
    ExtractDemoConfig and its SceneSettings: unset they keep the demo's values (kitchen, 128x128, 50, 12, occluded),
    given they change them, and --prune-only refuses them."""
    from dataclasses import replace

    from roodi_toolkit.cli.cmd_demo import (OBJECT_SETTING, OCCLUDED_SETTING, PRESET_SETTING, SCENE_SETTINGS)
    from roodi_toolkit.synth.demo import ExtractDemoConfig

    base = ExtractDemoConfig()
    cmd = _command("demo")

    def configs(args):
        values = cmd.make_context("demo", ["out", *args]).params
        scene = OCCLUDED_SETTING.config(values, base=SCENE_SETTINGS.config(values, base=base.scene))
        return OBJECT_SETTING.config(values, base=PRESET_SETTING.config(values, base=base)), scene

    assert configs([]) == (base, base.scene)
    assert (base.preset, base.scene.width, base.scene.height, base.scene.train_views, base.scene.test_views,
            base.scene.occluded) == ("kitchen", 128, 128, 50, 12, True)
    demo, scene = configs(["--preset", "bedroom", "--object", "3", "--size", "64x48", "--train-views", "7",
                           "--test-views", "2", "--no-occluded"])
    assert demo == replace(base, preset="bedroom", object_id=3)
    assert scene == replace(base.scene, width=64, height=48, train_views=7, test_views=2, occluded=False)
    assert configs(["--occluded"])[1].occluded
    text = " ".join(CliRunner().invoke(cmd, ["--help"]).output.split())
    for expected in ("--size TEXT Image size WIDTHxHEIGHT (or one number). [default: 128x128]",
                     "Views of each target alone. [default: 12; 1<=x<=1000]", "[default: occluded]",
                     "--preset [bedroom|kitchen|livingroom|picnic] Generated scene type. [default: kitchen]"):
        assert expected in text, expected
    assert CliRunner().invoke(cmd, ["out", "--size", "4"]).exit_code == 2
    res = CliRunner().invoke(cmd, ["out", "--prune-only", "--size", "64", "--no-occluded", "--object", "1"])
    assert res.exit_code == 2 and "--object, --size, --occluded/--no-occluded: options of the extraction demo" in \
        res.output, res.output


def test_flags_rename_a_setting_for_one_command():
    from roodi_toolkit.cli.settings import Options

    opts = Options(Outer, unset=True, only=("inner.steps",), flags={"inner.steps": "--steps-inside"})
    cmd = _toy(opts)
    assert [(p.opts, p.name) for p in cmd.params] == [(["--steps-inside"], "steps_inside")]
    assert opts.config(cmd.make_context("cmd", ["--steps-inside", "3"]).params) == Outer(inner=Inner(steps=3))
    with pytest.raises(TypeError, match="flags= of settings not offered: flat.steps"):
        Options(Outer, only=("inner.steps",), flags={"flat.steps": "--x"}).offered()


def test_demo_train_seed_is_the_train_configs_seed():
    """--train-seed is TrainConfig.seed under the demo's own flag (its --seed is the scene's): its range and
    default come from the field; unset it keeps the demo's training seed."""
    from dataclasses import replace

    from roodi_toolkit.cli.cmd_demo import TRAIN_SEED_SETTING
    from roodi_toolkit.pipeline.train import TrainConfig

    base = _demo_extract()
    (offered,) = TRAIN_SEED_SETTING.offered()
    assert (offered.option, offered.param, offered.path) == ("--train-seed", "train_seed", ("train", "seed"))
    assert offered.setting == next(d for d in declared(TrainConfig) if d.name == "seed")
    cmd = _command("demo")
    assert TRAIN_SEED_SETTING.config(cmd.make_context("demo", ["out"]).params, base=base) == base
    values = cmd.make_context("demo", ["out", "--train-seed", "5", "--seed", "7"]).params
    assert TRAIN_SEED_SETTING.config(values, base=base) == replace(base, train=replace(base.train, seed=5))
    assert values["seed"] == 7  # the scene's, a parameter of its own
    for bad in ("-1", str(2 ** 32)):
        assert CliRunner().invoke(cmd, ["out", "--train-seed", bad]).exit_code == 2, bad
    with pytest.raises(ConfigError, match="seed must be a whole number in"):
        TrainConfig(seed=-1)
