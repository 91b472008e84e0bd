"""Bad options on every command: non-finite, negative, zero, out-of-range, machine-sized and malformed values. Each
is refused before any work with one line naming the option (exit 2 for what click parses, 1 for what the command
checks), and nothing is written."""

from __future__ import annotations

from pathlib import Path

import pytest

from .conftest import expect_failure

NONFINITE = ["nan", "inf", "-inf", "NaN", "1e999"]

# (case id, args with {ply} {data} {model} {dist} {gen} {out} placeholders, exit code, what the line must name)
CASES: list[tuple[str, list[str], int, str]] = []


def case(name: str, args: str, code: int, needle: str) -> None:
    CASES.append((name, args.split(), code, needle))


for v in NONFINITE:
    case(f"prune alpha {v}", f"prune {{ply}} {{out}}/o.ply --alpha {v}", 2, "--alpha")
    case(f"prune min-opacity {v}", f"prune {{ply}} {{out}}/o.ply --min-opacity {v}", 2, "--min-opacity")
    case(f"render elevation {v}", f"render {{ply}} {{out}}/r --elevation {v}", 2, "--elevation")
    case(f"render radius {v}", f"render {{ply}} {{out}}/r --radius {v}", 2, "--radius")
    case(f"render fov {v}", f"render {{ply}} {{out}}/r --fov {v}", 2, "--fov")
    case(f"select threshold {v}", f"select {{dist}} {{out}}/o.ply --object 1 --threshold {v}", 2, "--threshold")
    case(f"distill classifier-lr {v}", f"distill {{model}} {{data}} {{out}}/d --classifier-lr {v}", 2,
         "--classifier-lr")
    case(f"distill feature-lr {v}", f"distill {{model}} {{data}} {{out}}/d --feature-lr {v}", 2, "--feature-lr")
    case(f"distill downscale {v}", f"distill {{model}} {{data}} {{out}}/d --downscale {v}", 2, "--downscale")
    case(f"train downscale {v}", f"train {{data}} {{out}}/t --downscale {v}", 2, "--downscale")
    case(f"extract threshold {v}", f"extract {{data}} {{out}}/e --object 1 --threshold {v}", 2, "--threshold")
    case(f"extract downscale {v}", f"extract {{data}} {{out}}/e --object 1 --downscale {v}", 2, "--downscale")

for bad in ["nan,0,0", "2,0,0", "-1,0,0", "1,1", "a,b,c", "inf,0,0"]:
    case(f"render background {bad}", f"render {{ply}} {{out}}/r --background {bad}", 2, "--background")
for bad in ["0,0,0", "nan,0,1", "1,2", "x,y,z", "inf,0,0"]:
    case(f"render up {bad}", f"render {{ply}} {{out}}/r --up {bad} --orbit 1 --size 8x8 -q",
         1, "--up")  # --up also takes a dataset or 'auto': the library parses it (ConfigError, exit 1)
for bad in ["0x0", "-8x8", "99999x8", "axb", "8x", "16385"]:
    case(f"render size {bad}", f"render {{ply}} {{out}}/r --size {bad}", 2, "--size")
for bad in ["16384x16384", "4097x10", "0x0", "wide"]:
    case(f"inspect window-size {bad}", f"inspect {{ply}} --window-size {bad} --histogram {{out}}/h.png", 2,
         "--window-size")
for bad in ["0", "-1", "100000", "abc", "1.5", "", "nan"]:
    case(f"threads {bad!r}", f"--threads={bad} render {{ply}} {{out}}/r --orbit 1 --size 8x8 -q", 1, "--threads")
for bad in ["0", "-3", "4000"]:
    case(f"render orbit {bad}", f"render {{ply}} {{out}}/r --orbit {bad}", 2, "--orbit")
for bad in ["0", "-1", "x"]:
    case(f"prune k {bad}", f"prune {{ply}} {{out}}/o.ply --k {bad}", 2, "--k")
case("prune k above cloud", "prune {ply} {out}/o.ply --k 1000000000", 1, "--k")
for bad, code in [("1,1,1,0,0,0", 1), ("1,2,3", 2), ("a,b,c,d,e,f", 2)]:
    case(f"prune filter-box {bad}", f"prune {{ply}} {{out}}/o.ply --filter-box {bad}", code, "box")
for bad, code in [("0,0,0,-1", 1), ("0,0,0,nan", 2), ("0,0,0", 2), ("0,0,0,inf", 2)]:
    case(f"prune filter-sphere {bad}", f"prune {{ply}} {{out}}/o.ply --filter-sphere {bad}", code, "sphere")
for cmd in ["make-scene {out}/s --size 8x8", "train {data} {out}/t", "distill {model} {data} {out}/d",
            "benchmark {out}/r {out}/b", "demo {out}/d"]:
    for bad in ["-1", "4294967296", "1e3", "x"]:
        case(f"{cmd.split()[0]} seed {bad}", f"{cmd} --seed {bad}", 2, "--seed")
for bad in ["0", "-5"]:
    case(f"train iterations {bad}", f"train {{data}} {{out}}/t --iterations {bad}", 2, "--iterations")
    case(f"distill iterations {bad}", f"distill {{model}} {{data}} {{out}}/d --iterations {bad}", 2, "--iterations")
    case(f"make-scene train-views {bad}", f"make-scene {{out}}/s --train-views {bad}", 2, "--train-views")
    case(f"evaluate max-views {bad}", f"evaluate {{ply}} {{gen}} --object 1 --max-views {bad}", 2, "--max-views")
for bad in ["4", "-1", "x"]:
    case(f"train sh-degree {bad}", f"train {{data}} {{out}}/t --sh-degree {bad}", 2, "--sh-degree")
for bad in ["16384x16384", "0x0", "7x7", "axb"]:  # SceneSettings' sides (8 to 8192) checked as --size is read
    case(f"make-scene size {bad}", f"make-scene {{out}}/s --size {bad} -q", 2, "--size")
case("select object negative", "select {dist} {out}/o.ply --object -1", 2, "--object")
case("select threshold 0", "select {dist} {out}/o.ply --object 1 --threshold 0", 2, "--threshold")
case("select threshold 1", "select {dist} {out}/o.ply --object 1 --threshold 1", 2, "--threshold")
case("select unknown object", "select {dist} {out}/o.ply --object 9", 1, "9")
case("evaluate unknown target", "evaluate {ply} {gen} --object 77", 1, "77")
case("evaluate target not an int", "evaluate {ply} {gen} --object one", 2, "--object")
case("benchmark unknown preset", "benchmark {out}/r {out}/b --preset attic", 1, "attic")
case("benchmark unknown method", "benchmark {out}/r {out}/b --method magic", 1, "magic")
case("benchmark size 1", "benchmark {out}/r {out}/b --size 1", 2, "--size")
case("render renderer unknown", "render {ply} {out}/r --renderer nope", 1, "nope")
case("extract inpainter unknown", "extract {data} {out}/e --object 1 --inpainter nope -q", 1, "nope")
case("distill segmenter unknown", "distill {model} {data} {out}/d --segmenter nope -q", 1, "nope")
case("render cameras and orbit", "render {ply} {out}/r --cameras {data} --orbit 2", 2, "--orbit")
case("unknown command", "frobnicate", 2, "frobnicate")
case("unknown option", "info {ply} --frobnicate", 2, "--frobnicate")
case("missing argument", "prune {ply}", 2, "OUT")


@pytest.mark.parametrize("name,args,code,needle", CASES, ids=[c[0] for c in CASES])
def test_bad_option_is_refused_naming_it(name: str, args: list[str], code: int, needle: str, world, run_cli,
                                         tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("ROODI_THREADS", "1")  # --threads writes it; keep the next cases' default
    out = tmp_path / "out"
    out.mkdir()
    values = {"ply": world.ply, "data": world.data, "model": world.model, "dist": world.dist, "gen": world.gen,
              "out": out}
    res = run_cli(*[a.format(**values) for a in args])
    expect_failure(res, code, needle)
    assert list(out.iterdir()) == []  # refused before anything was written
    assert world.unchanged()
