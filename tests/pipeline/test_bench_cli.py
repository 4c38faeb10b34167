"""ibr-bench: parameter sweeps, run time against error (ibrtools.pipeline.sweep, cli/ibrtools_cli/bench.py)."""
from __future__ import annotations

import csv
from pathlib import Path

import pytest

from ibrtools.errors import BadValueError
from ibrtools.pipeline.sweep import configurations, pareto, parse_sweep
from ibrtools_cli import bench


def test_sweep_grammar():
    g = parse_sweep(["sigma=1:3:5,alpha=7", "tau_var=0.5:0.82", "filtered=true:false,name=x"])
    assert g == {"sigma": [1, 3, 5], "alpha": [7], "tau_var": [0.5, 0.82], "filtered": [True, False], "name": ["x"]}
    assert len(configurations(g)) == 3 * 2 * 2
    assert configurations({"a": [1, 2]}, {"b": 0}) == [{"b": 0, "a": 1}, {"b": 0, "a": 2}]
    assert parse_sweep(None) == {} and configurations({}) == [{}]
    for bad in (["sigma"], ["=1"], ["sigma=1:"], ["sigma=1,sigma=2"], ["sigma=nan"]):
        with pytest.raises(BadValueError):
            parse_sweep(bad)


def test_pareto_front():
    rows = [{"median_ms": 10, "mean_flip": 0.2}, {"median_ms": 20, "mean_flip": 0.1},
            {"median_ms": 30, "mean_flip": 0.15}, {"median_ms": 5, "mean_flip": None}]
    assert pareto(rows) == [0, 1]


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from ibrtools.pipeline import stages as S

    d = tmp_path_factory.mktemp("bench") / "scene"
    S.preprocess("synth:objects", d, synth={"preset": "objects", "size": [48, 36], "views": 4, "seed": 0,
                                            "reconstructed": False, "holdout_targets": 1},
                 methods=["tm", "ulr"], stage_options={"mesh": {"source": "ground_truth", "resolution": 64}})
    return d


def test_bench_ulr_sweep_writes_csv_plot_table(scene_dir, tmp_path, capsys):
    out = tmp_path / "sweep"
    assert bench.main([str(scene_dir), "--method", "ulr", "--sweep", "k=2:4", "--sweep", "depth_tol=0.02",
                       "--holdout", "v001", "-o", str(out), "-q"]) == 0
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [r["k"] for r in rows] == ["2", "4"] and all(r["depth_tol"] == "0.02" for r in rows)
    assert all(float(r["mean_psnr"]) > 15 and float(r["median_ms"]) > 0 for r in rows)
    assert (out / "sweep.png").stat().st_size > 1000
    md = (out / "sweep.md").read_text()
    assert "| config | k | depth_tol |" in md and md.count("\n|") >= 4
    # No sweep at all: one configuration, the scene's targets.
    assert bench.main([str(scene_dir), "--method", "tm", "-o", str(tmp_path / "one"), "-q"]) == 0
    assert len(list(csv.DictReader(open(tmp_path / "one" / "sweep.csv")))) == 1


@pytest.mark.parametrize("argv, msg", [
    (["--method", "ulr", "--sweep", "k=0"], "--sweep k: expected an integer >= 1"),
    (["--method", "ulr", "--sweep", "magic=1"], "no parameter"),
    (["--method", "ulr", "--sweep", "k"], "--sweep"),
    (["--method", "ulr", "--sweep", "k=2", "--param", "k=3"], "both set"),
    (["--method", "ulr", "--holdout", "nope"], "nope"),
])
def test_bench_bad_input_one_line_exit_2(scene_dir, tmp_path, capsys, argv, msg):
    assert bench.main([str(scene_dir), *argv, "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ibr-bench: error:") and msg in err and err.count("\n") == 1


def test_bench_missing_scene_and_stage(tmp_path, capsys):
    assert bench.main([str(tmp_path / "none"), "--method", "tm", "-o", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.startswith("ibr-bench: error:")


def test_bench_json_html_and_totals(scene_dir, tmp_path, capsys):
    import json

    out = tmp_path / "j"
    assert bench.main([str(scene_dir), "--method", "ulr", "--sweep", "k=2:3", "--holdout", "v001",
                       "-o", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)  # stdout holds the JSON alone
    assert doc["method"] == "ulr" and doc["swept"] == ["k"] and [r["k"] for r in doc["configurations"]] == [2, 3]
    assert all(Path(f).is_file() for f in doc["files"].values()) and cap.err == ""
    assert (out / "report.html").read_text().startswith("<!DOCTYPE html>")
    # v001 was an input of the mesh stage ULR reads: the JSON carries the note, the table run prints it.
    assert "held-out view v001 was an input of the mesh" in doc["holdout_note"]
    assert bench.main([str(scene_dir), "--method", "ulr", "--sweep", "k=2:3", "--holdout", "v001",
                       "-o", str(out)]) == 0
    cap = capsys.readouterr()
    text = cap.out
    assert "best:" in text and "fastest" in text and "report.html" in text
    assert "ibr-bench: note: held-out view v001" in cap.err and "optimistic" in cap.err
