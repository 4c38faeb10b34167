"""The ``mvs`` stage in the planner: photographs and cameras alone go to new views (dibr), the
stage is cached and skipped when every view has depth, and the commands that errors suggest work."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from conftest import photos_only

from ibrtools.pipeline import stages as S
from ibrtools import cache
from ibrtools_cli import preprocess, render


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    base = tmp_path_factory.mktemp("mvsstage")
    assert preprocess.main(["synth:objects", "-o", str(base / "full"), "--views", "8", "--size", "240x180",
                            "-q"]) == 0
    return base, photos_only(base / "full", base / "photos")


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
    arrays = cache.load_npz(cache.stage_output(s, "mvs"))
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
    assert rep["frames"][0]["metrics"]["psnr_covered"] > 18
    # Unchanged inputs: up to date; a changed parameter: ran again.
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr", "--json", "--set", "mvs.iterations=4"]) == 0
    assert {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]["status"] == "up to date"
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr", "--json", "--set", "mvs.iterations=3"]) == 0
    assert {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]["status"] == "ran"
    # A view that changes: ran again.
    from ibrtools.imageio import read_image, write_image

    img = s / "images" / "v000.png"
    write_image(img, np.clip(read_image(img) * 0.9, 0, 1))
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr", "--json", "--set", "mvs.iterations=3"]) == 0
    row = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]
    assert row["status"] == "ran" and "changed" in row["reason"]


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


def test_a_users_mesh_gives_the_views_depth(tmp_path, capsys):
    """--mesh FILE: the mesh is the scene's reconstructed mesh; views without depth get its
    rendering (the depth stage) and dibr renders from it; no multi-view stereo."""
    from ibrtools.camera import Camera, look_at
    from ibrtools.formats import native
    from ibrtools.mesh import Mesh
    from ibrtools.meshio import write_mesh
    from ibrtools.scene import Scene, View

    v = np.array([[-3, -3, 2], [3, -3, 2], [3, 3, 2], [-3, 3, 2]], np.float32)
    write_mesh(tmp_path / "wall.ply", Mesh(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32)))
    rng = np.random.default_rng(0)
    views = [View.create(f"v{i}", Camera.pinhole(48, 36, 36.0, 36.0, 24.0, 18.0,
                                                  look_at((x, 0, 0), (x, 0, 2), up=(0, -1, 0))),
                         color=rng.uniform(0, 1, (36, 48, 3)).astype(np.float32))
             for i, x in enumerate((-0.2, 0.0, 0.2))]
    native.save(Scene(views=views), tmp_path / "src")
    s = tmp_path / "s"
    assert preprocess.main([str(tmp_path / "src"), "-o", str(s), "--mesh", str(tmp_path / "wall.ply"),
                            "--methods", "dibr", "--json", "--set", "mesh.resolution=16"]) == 0
    rows = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["mvs"]["status"] == "skipped" and "reconstructed mesh" in rows["mvs"]["reason"]
    assert rows["mesh"]["status"] == "ran" and rows["depth"]["status"] == "ran"
    dep = cache.load_npz(cache.stage_output(s, "depth"))
    np.testing.assert_allclose(dep["v1"][dep["v1"] > 0], 2.0, rtol=1e-4)
    assert render.main([str(s), "--method", "dibr", "--holdout", "v1", "-o", str(tmp_path / "o"), "-q"]) == 0
    # --mesh in place (nothing imported) is refused in one line; a missing file names itself.
    assert preprocess.main([str(s), "-o", str(s), "--mesh", str(tmp_path / "wall.ply")]) == 2
    assert "--mesh: only when importing" in capsys.readouterr().err
    assert preprocess.main([str(tmp_path / "src"), "-o", str(tmp_path / "t"), "--mesh", str(tmp_path / "no.ply")]) == 2
    assert "no.ply" in capsys.readouterr().err


def test_the_stage_refuses_a_run_beyond_the_memory_in_one_line(photos, capsys, tmp_path, monkeypatch):
    _, scene = photos
    s = tmp_path / "s"
    shutil.copytree(scene, s)
    monkeypatch.setenv("IBR_MEMORY_LIMIT", "100M")
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mvs: multi-view stereo of 8 views" in err, err
    assert "mvs" not in json.loads((s / "scene.json").read_text()).get("stages", {})


def test_outside_the_masks_of_a_scene_with_a_background_is_the_background(photos, capsys, tmp_path):
    # An RGBA capture (nerf synthetic: shading.background, mask = alpha > 1/2) says its empty pixels
    # are the background at infinity: the stage writes +inf there (docs/FORMAT.md "Background"), so
    # dibr renders the background, not holes filled with smeared surface.
    from ibrtools.formats import native
    from ibrtools.imageio import write_image

    base, scene = photos
    s = tmp_path / "s"
    shutil.copytree(scene, s)
    truth = native.load(base / "full")
    doc = json.loads((s / "scene.json").read_text())
    assert doc["shading"]["background"] == [0.0, 0.0, 0.0]
    for v, entry in zip(truth.views, doc["views"]):
        write_image(s / "images" / f"{v.name}.mask.png", np.isfinite(v.depth).astype(np.float32)[..., None])
        entry["mask"] = f"images/{v.name}.mask.png"
    (s / "scene.json").write_text(json.dumps(doc))
    assert preprocess.main([str(s), "-o", str(s), "--methods", "dibr", "--json", "--set", "mvs.iterations=2"]) == 0
    row = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]
    assert row["background_pixels"] == sum(int(np.isinf(v.depth).sum()) for v in truth.views) > 0
    arrays = cache.load_npz(cache.stage_output(s, "mvs"))
    for v in truth.views:
        d = arrays[f"depth:{v.name}"]
        assert np.array_equal(np.isposinf(d), np.isinf(v.depth))  # exactly the pixels outside the mask
        assert np.all(arrays[f"confidence:{v.name}"][np.isinf(d)] == 0)  # not a surface measurement
    out = tmp_path / "o"
    assert render.main([str(s), "--method", "dibr", "--holdout", "v002", "-o", str(out), "-q", "--depth"]) == 0
    from ibrtools.imageio import read_depth

    # The sky the neighbours see in the held-out view's directions is background (without masks the
    # views' empty pixels are unknown and the render has no background at all).
    assert np.isposinf(read_depth(out / "v002.depth.exr")).mean() > 0.03
