"""The settings declarations (roodi_toolkit.settings): types read from the annotations, ranges and choices checked
by the dataclass, command-line text read the same way everywhere."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.settings import check_settings, declared, describe_range, parse_floats, parse_text, setting


@dataclass(frozen=True)
class Toy:
    count: int = setting(4, "How many.", low=1)
    share: float = setting(0.5, "A share.", low=0, high=1, high_open=True)
    limit: float = setting(2.0, "A limit, infinite allowed.", finite=False)
    colour: str = setting("red", "A colour.", choices=("red", "blue"))
    strict: bool = setting(False, "A flag.")
    cap: float | None = setting(None, "An optional cap.", low=0, low_open=True)
    where: tuple[float, float, float] | None = setting(None, "A point.", option="--at", metavar="X,Y,Z")
    tags: tuple[tuple[str, float], ...] = setting((), "Tags.", parse=lambda t: (t.split(":")[0],
                                                                             float(t.split(":")[1])))
    hidden: int = setting(3, "Library only.", cli=False)

    def __post_init__(self) -> None:
        check_settings(self)


def test_declared_reads_each_setting_from_its_field():
    got = {d.name: (d.kind, d.optional, d.repeated, d.size, d.option, d.default) for d in declared(Toy)}
    assert got == {
        "count": (int, False, False, 0, "--count", 4), "share": (float, False, False, 0, "--share", 0.5),
        "limit": (float, False, False, 0, "--limit", 2.0), "colour": (str, False, False, 0, "--colour", "red"),
        "strict": (bool, False, False, 0, "--strict", False), "cap": (float, True, False, 0, "--cap", None),
        "where": (tuple, True, False, 3, "--at", None), "tags": (tuple, False, True, 0, "--tags", ()),
        "hidden": (int, False, False, 0, "--hidden", 3)}
    assert declared(Toy()) == declared(Toy)  # an instance works too
    assert [d.meta.cli for d in declared(Toy)][-1] is False


def test_a_field_without_a_declaration_is_a_programming_error():
    @dataclass
    class Loose:
        a: int = 1
        b: int = field(default=2)

    with pytest.raises(TypeError, match="Loose.a is not declared"):
        declared(Loose)

    @dataclass
    class Odd:
        a: dict = setting(None, "A dict.")

    with pytest.raises(TypeError, match="unsupported setting type"):
        declared(Odd)

    @dataclass
    class Many:
        a: tuple[int, ...] = setting((), "Ints.")

    with pytest.raises(TypeError, match="needs parse="):
        declared(Many)


@pytest.mark.parametrize("kwargs,message", [
    ({"count": 0}, "count must be a whole number >= 1, got 0"),
    ({"count": 2.0}, "count must be a whole number >= 1, got 2.0"),
    ({"count": True}, "count must be a whole number"),
    ({"share": 1.0}, r"share must be a finite number in \[0, 1\), got 1.0"),
    ({"share": math.nan}, "share must be"),
    ({"share": math.inf}, "share must be"),
    ({"limit": math.nan}, "limit must be a number, got nan"),
    ({"colour": "green"}, "colour must be one of red, blue, got 'green'"),
    ({"strict": 1}, "strict must be true or false"),
    ({"cap": 0.0}, r"cap must be a finite number > 0 or None, got 0.0"),
    ({"where": (1.0, 2.0)}, "where must be 3 finite numbers or None"),
    ({"where": (1.0, math.nan, 2.0)}, "where must be 3 finite numbers"),
    ({"tags": "a:1"}, "tags must be a list"),
    ({"hidden": 1.5}, "hidden must be a whole number, got 1.5"),
])
def test_check_settings_refuses_values_outside_the_declared_space(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        Toy(**kwargs)


def test_check_settings_takes_values_inside_the_declared_space():
    import numpy as np

    toy = Toy(count=np.int64(2), share=0.0, limit=math.inf, colour="blue", strict=np.bool_(True), cap=3,
              where=(1, 2, 3), tags=(("a", 1.0),), hidden=0)
    assert toy.limit == math.inf and toy.count == 2


def test_describe_range_says_the_value_space_in_words():
    by_name = {d.name: describe_range(d) for d in declared(Toy)}
    assert by_name["count"] == "a whole number >= 1"
    assert by_name["share"] == "a finite number in [0, 1)"
    assert by_name["cap"] == "a finite number > 0"
    assert by_name["colour"] == "one of red, blue"


def test_text_of_tuple_settings_is_read_as_comma_separated_numbers():
    where = next(d for d in declared(Toy) if d.name == "where")
    tags = next(d for d in declared(Toy) if d.name == "tags")
    assert parse_text(where, "1, 2,3") == (1.0, 2.0, 3.0)
    assert parse_text(tags, "a:2") == ("a", 2.0)
    with pytest.raises(ValueError, match="expected 3 comma-separated numbers, got 2"):
        parse_text(where, "1,2")
    with pytest.raises(ValueError, match="expected 3 comma-separated numbers, got 'a,b,c'"):
        parse_floats("a,b,c", 3)
    with pytest.raises(ValueError, match="expected finite numbers"):
        parse_floats("1,inf,2", 3)


def test_documented_lists_every_setting_in_the_docstring():
    from roodi_toolkit.prune.config import PruneConfig
    from roodi_toolkit.settings import documented

    doc = documented(type("Copy", (Toy,), {"__doc__": "A toy."})).__doc__
    assert doc.startswith("A toy.\n\n    Attributes:\n")
    assert "count: How many. (default 4; a whole number >= 1; --count)" in doc
    assert "cap: An optional cap. (default None; a finite number > 0 or None; --cap)" in doc
    assert "hidden: Library only. (default 3; a whole number; library only)" in doc
    text = " ".join(PruneConfig.__doc__.split())  # lines are wrapped
    assert all(f" {d.name}: {d.meta.help} (default {d.default!r};" in text for d in declared(PruneConfig))
    assert max(len(line) for line in PruneConfig.__doc__.splitlines()) <= 116


def test_documented_writes_a_nested_configs_default_by_what_differs():
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.pipeline.train import TrainConfig

    doc = " ".join(TrainConfig.__doc__.split())
    assert "strategy: The MCMC densification's settings. (default MCMCStrategy(cap_max=60000); a MCMCStrategy" in doc
    doc = " ".join(ExtractConfig.__doc__.split())
    assert "(default FinetuneConfig(); a FinetuneConfig; its settings' options as --finetune-NAME)" in doc
    assert "(default TrainConfig(); a TrainConfig; its settings' options)" in doc


def test_nested_configs_and_library_values_are_checked_by_their_type():
    @dataclass(frozen=True)
    class Outer:
        inner: Toy = setting(factory=Toy, help="A nested config.", prefix="toy")
        notes: dict = setting(factory=dict, help="Library only.", cli=False)

        def __post_init__(self) -> None:
            check_settings(self)

    kinds = {d.name: (d.kind, d.nested, d.default) for d in declared(Outer)}
    assert kinds == {"inner": (Toy, True, Toy()), "notes": (dict, False, {})}
    with pytest.raises(ConfigError, match="inner must be a Toy, got 3"):
        Outer(inner=3)
    with pytest.raises(ConfigError, match="notes must be a dict"):
        Outer(notes=[])

    @dataclass
    class Wrong:
        a: int = setting(1, "Not a config.", prefix="a")

    with pytest.raises(TypeError, match="prefix= is for a nested config"):
        declared(Wrong)

    @dataclass
    class Offered:
        a: Toy = setting(factory=Toy, help="A config offered without a prefix.")

    with pytest.raises(TypeError, match="a nested config takes prefix="):
        declared(Offered)


def test_a_flag_on_by_default_is_offered_as_no_name():
    @dataclass(frozen=True)
    class Flags:
        prune: bool = setting(True, "Prune; --no-prune skips it.")
        quick: bool = setting(False, "Go quickly.")
        both: bool | None = setting(None, "One or the other.", option="--this/--that")

    assert [(d.option, d.negated) for d in declared(Flags)] == [("--no-prune", True), ("--quick", False),
                                                                 ("--this/--that", False)]


@dataclass(frozen=True)
class Sized:
    width: int = setting(20, "Image size WIDTHxHEIGHT.", low=8, option="--size", joins=("height",),
                         parse=lambda t: tuple(int(v) for v in t.split("x")), write=lambda v: f"{v[0]}x{v[1]}")
    height: int = setting(10, "Image height.", low=8, cli=False)

    def __post_init__(self) -> None:
        check_settings(self)


def test_a_setting_that_joins_others_needs_parse_and_write_and_each_field_keeps_its_range():
    from roodi_toolkit.settings import documented

    width = declared(Sized)[0]
    assert width.meta.joins == ("height",) and parse_text(width, "30x9") == (30, 9)
    with pytest.raises(ConfigError, match="height must be a whole number >= 8, got 4"):
        Sized(height=4)
    with pytest.raises(TypeError, match="joins others needs parse= and write="):
        @dataclass
        class Broken:
            width: int = setting(20, "W.", joins=("height",))
            height: int = setting(10, "H.", cli=False)

        declared(Broken)
    doc = documented(type("Doc", (Sized,), {"__doc__": "Sized."})).__doc__
    assert "height: Image height. (default 10; a whole number >= 8; with --size)" in doc


def test_image_sizes_are_read_as_width_x_height_or_one_number():
    from roodi_toolkit.settings import parse_image_size, write_image_size

    assert parse_image_size("64x48") == (64, 48) and parse_image_size(" 32 ") == (32, 32)
    assert parse_image_size(write_image_size((7, 9))) == (7, 9)
    for text, message in (("wide", "expected WIDTHxHEIGHT"), ("0", "between 1 and 16384"),
                          ("8x7", "between 8 and 20")):
        with pytest.raises(ValueError, match=message):
            parse_image_size(text, *((8, 20) if text == "8x7" else ()))


def test_key_value_text_is_read_by_each_settings_type_and_checked_by_the_class():
    """``--segmenter-option KEY=VALUE`` text: config_from_text reads it by the declaration and names the option."""
    from roodi_toolkit.settings import config_from_text, parse_value

    by_name = {d.name: d for d in declared(Toy)}
    assert [parse_value(by_name[n], t) for n, t in (("count", "7"), ("share", "0.25"), ("strict", "yes"),
                                                     ("strict", "off"), ("colour", "blue"), ("cap", "none"),
                                                     ("where", "1,2,3"))] == [7, 0.25, True, False, "blue", None,
                                                                              (1.0, 2.0, 3.0)]
    assert config_from_text(Toy, {"count": "7", "cap": "2", "share": 0.1}, "toy option") == Toy(count=7, cap=2.0,
                                                                                                share=0.1)
    for values, message in (({"count": "many"}, "toy option count='many': expected a whole number >= 1"),
                            ({"strict": "maybe"}, "toy option strict='maybe': expected true or false"),
                            ({"count": "0"}, "toy option: count must be a whole number >= 1, got 0"),
                            ({"colour": "green"}, "toy option: colour must be one of red, blue, got 'green'"),
                            ({"size": "1"}, "toy option size: no setting of Toy; its settings are count, share")):
        with pytest.raises(ConfigError) as err:
            config_from_text(Toy, values, "toy option")
        assert str(err.value).startswith(message), str(err.value)


def test_documented_can_say_how_a_command_line_gives_each_setting():
    from roodi_toolkit.settings import documented

    @documented(given="--thing-option {name}=VALUE")
    @dataclass(frozen=True)
    class Thing:
        """A thing."""

        size: int = setting(3, "Its size.", low=1)

    assert "size: Its size. (default 3; a whole number >= 1; --thing-option size=VALUE)" in Thing.__doc__
