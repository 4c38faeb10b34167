"""The ``mvs`` stage in the planner: photographs and cameras alone go to new views (dibr), the
stage is cached and skipped when every view has depth, and the commands that errors suggest work."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from ibrtools import stages as S
from ibrtools_cli import preprocess, render


def _strip_depth(src: Path, dst: Path) -> Path:
    """A copy of the scene at ``src`` whose views have colour only (no depth, no mesh, no stages)."""
    shutil.copytree(src, dst)
    doc = json.loads((dst / "scene.json").read_text())
    for v in doc["views"]:
        v.pop("depth", None)
        v.pop("depth_stored", None)
    doc["meshes"], doc["stages"] = {}, {}
    (dst / "scene.json").write_text(json.dumps(doc))
    return dst


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    base = tmp_path_factory.mktemp("mvsstage")
    assert preprocess.main(["synth:objects", "-o", str(base / "full"), "--views", "8", "--size", "240x180",
                            "-q"]) == 0
    return base, _strip_depth(base / "full", base / "photos")


def test_photographs_go_to_new_views(photos, capsys, tmp_path):
    base, scene = photos
    s = tmp_path / "s"
    shutil.copytree(scene, s)
    # Before the stage: dibr says what to run, and that command then works.
    assert render.main([str(s), "--method", "dibr", "--holdout", "v002", "-o", str(tmp_path / "o0"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"ibr-preprocess {s} -o {s} --methods dibr" in err and len(err.splitlines()) == 1
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr", "--json",
                            "--set", "mvs.iterations=4"]) == 0
    rows = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["mvs"]["status"] == "ran" and rows["mvs"]["views"] == 8
    assert set(rows["mvs"]["sources"]) == {f"v{i:03d}" for i in range(8)}
    assert all(rows["mvs"]["sources"].values())
    rec = json.loads((s / "scene.json").read_text())["stages"]["mvs"]
    assert rec["details"]["sources"] == rows["mvs"]["sources"] and rec["params"]["iterations"] == 4
    arrays = S.load_npz(S.stage_output(s, "mvs"))
    full = json.loads((base / "full" / "scene.json").read_text())
    from ibrtools.formats import native

    truth = native.load(base / "full")
    kept = within = 0
    for v in truth.views:
        d = arrays[f"depth:{v.name}"]
        k = (d > 0) & (v.depth > 0)
        kept += k.sum()
        within += (np.abs(d[k] - v.depth[k]) < 0.01 * v.depth[k]).sum()
        assert arrays[f"normal:{v.name}"].shape == d.shape + (3,)
        c = arrays[f"confidence:{v.name}"]
        assert np.all((c > 0) == (d > 0)) and c.max() <= 1
    assert kept > 0 and within / kept > 0.8, within / kept
    assert full  # (the ground truth scene is untouched)
    # Now dibr renders the held-out view from the photographs' depth.
    out = tmp_path / "o1"
    assert render.main([str(s), "--method", "dibr", "--holdout", "v002", "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["frames"][0]["metrics"]["coverage"] > 0.08
    assert rep["frames"][0]["metrics"]["psnr_masked"] > 18
    # Unchanged inputs: up to date; a changed parameter: ran again.
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr", "--json", "--set", "mvs.iterations=4"]) == 0
    assert {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]["status"] == "up to date"
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr", "--json", "--set", "mvs.iterations=3"]) == 0
    assert {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]["status"] == "ran"


def test_skipped_when_every_view_has_depth(photos, capsys):
    base, _ = photos
    assert preprocess.main([str(base / "full"), "-o", str(base / "full"), "--methods", "dibr", "--json"]) == 0
    row = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]
    assert row["status"] == "skipped" and row["reason"] == "every view has depth"


def test_bad_mvs_options_are_one_line(photos, capsys, tmp_path):
    _, scene = photos
    for arg, key in (("mvs.nosuch=1", "mvs.nosuch"), ("mvs.window_radius=99", "mvs.window_radius"),
                     ("mvs.depth_range=3,1", "mvs.depth_range")):
        assert preprocess.main([str(scene), "-o", str(tmp_path / "x"), "--methods", "dibr", "--set", arg]) == 2
        err = capsys.readouterr().err.strip()
        assert key in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "x").exists()
