import json

from roodi_toolkit import read_ply


def test_demo_writes_pruned_cloud_picture_and_report(tmp_path, run_cli):
    out = tmp_path / "demo"
    res = run_cli("demo", out, "--surface", "sphere", "-q")
    assert res.exit_code == 0, res.stderr
    assert "far floaters removed" in res.stdout
    report = json.loads((out / "report.json").read_text())
    truth = report["planted_truth"]
    assert truth["far_removed"] >= 0.95 and truth["near_removed"] >= 0.95 and truth["object_lost"] <= 0.01
    pruned, floaters = read_ply(out / "pruned.ply"), read_ply(out / "floaters.ply")
    assert len(pruned) + len(floaters) == len(read_ply(out / "with_floaters.ply"))
    assert (out / "prune_demo.png").stat().st_size > 10_000
    again = run_cli("demo", out, "-q")
    assert again.exit_code == 1 and "--overwrite" in again.stderr
