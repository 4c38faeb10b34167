"""The stage planner (ibrtools.pipeline.stages, ibr-preprocess): stages run for the methods that need
them, a second run does nothing, missing or corrupt outputs are rebuilt, parameters and
--stages / --force override, records in scene.json, bad input."""
import json
import os

import numpy as np
import pytest

from ibrtools import cache
from ibrtools.pipeline import stages as S
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, InputError
from ibrtools.formats import native
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene, View
from ibrtools_cli import preprocess

SMALL = ["--views", "3", "--size", "48x36", "--set", "mesh.resolution=32"]


def run(d, *extra, capsys):
    assert preprocess.main(["synth:objects", "-o", str(d), *SMALL, "--json", *extra]) == 0
    return {r["stage"]: r for r in json.loads(capsys.readouterr().out)}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("stages") / "scene"
    rows = {r.name: r for r in S.preprocess(
        "synth:objects", d, synth={"preset": "objects", "size": [48, 36], "views": 3, "seed": 0,
                                   "reconstructed": False},
        methods=["tm", "ulr", "pvm", "hybrid"], stage_options={"mesh": {"resolution": 32}})}
    return d, rows


def test_hybrid_methods_run_every_stage_then_nothing(built, capsys):
    d, rows = built
    assert rows["import"].status == "ran"
    for name in ("mesh", "texture", "pvm"):
        assert rows[name].status == "ran", rows[name]
    assert rows["depth"].status == "skipped" and "every view has depth" in rows["depth"].reason
    assert rows["mesh"].details["source"] == "fusion"
    # 3 views: the mix stage's leave-one-out fit needs 4; the hybrid then takes pvm_floor 0.
    assert rows["mix"].status == "skipped" and "needs >= 4" in rows["mix"].reason
    for name in ("mesh", "texture", "pvm"):
        assert (d / "cache" / name).is_dir()
    doc = json.loads((d / "scene.json").read_text())
    rec = doc["stages"]["pvm"]
    assert len(rec["key"]) == 32 and "tiles.npz" in rec["outputs"] and rec["params"]["coarse"] == 32
    # The per-view meshes snap to the global mesh within mesh_snap (2) voxels of it.
    voxel = doc["stages"]["mesh"]["details"]["voxel"]
    assert rec["params"]["mesh_snap"] == 2.0 and rec["details"]["snap"] == pytest.approx(2 * voxel, rel=1e-3)
    # Second run with nothing changed: every stage up to date or skipped, and it says so.
    out = run(d, "--methods", "tm,ulr,pvm,hybrid", capsys=capsys)
    assert {r["status"] for r in out.values()} <= {"up to date", "skipped"}
    assert out["pvm"]["status"] == "up to date"
    assert preprocess.main(["synth:objects", "-o", str(d), *SMALL, "--methods", "tm,ulr,pvm,hybrid"]) == 0
    assert "nothing to do" in capsys.readouterr().out


def test_texture_and_variance_share_one_statistics_pass(built, tmp_path, monkeypatch):
    """A fused mesh is its own render mesh: in one run the texture stage's gains and the variance
    stage come from one vertex_statistics pass, and the outputs equal those of the stages run
    apart (and of the first build)."""
    import shutil

    import ibrtools.hybrid.variance as V

    d, _ = built
    assert "render_vertices" not in np.load(d / "cache" / "mesh" / "mesh.npz").files
    ref = {n: dict(np.load(d / "cache" / n / f"{n}.npz")) for n in ("texture", "variance")}
    calls = []
    real = V.vertex_statistics
    monkeypatch.setattr(V, "vertex_statistics", lambda *a, **k: calls.append(1) or real(*a, **k))
    for stages, n_calls in (("texture,variance", 1), ("variance", 1), ("texture", 1)):
        d2 = tmp_path / stages.replace(",", "_")
        shutil.copytree(d, d2)
        calls.clear()
        assert preprocess.main([str(d2), "-o", str(d2), "--stages", stages, "--force", "--set", "mesh.resolution=32",
                                "-q"]) == 0
        assert len(calls) == n_calls, stages
        for n in stages.split(","):
            got = np.load(d2 / "cache" / n / f"{n}.npz")
            assert set(got.files) == set(ref[n]) and all(np.array_equal(got[k], ref[n][k]) for k in got.files), n


def test_vertex_statistics_are_released_once_no_stage_reads_them(built, tmp_path, monkeypatch):
    """The per-view samples of the statistics pass (on lego ~0.3 GB of the run's peak) are dropped
    before the stages after the variance stage run, and the outputs do not change."""
    import shutil

    d, _ = built
    d2 = tmp_path / "s"
    shutil.copytree(d, d2)
    held = {}  # stage -> how many statistics passes the run holds when the stage starts

    def recording(name, real):
        def run(ctx):
            held[name] = len(ctx._stats)
            return real(ctx)
        return run

    for name in ("texture", "variance", "harmonise", "pvm"):
        monkeypatch.setitem(S._RUN, name, recording(name, S._RUN[name]))
    assert preprocess.main([str(d2), "-o", str(d2), "--stages", "texture,variance,harmonise,pvm", "--force",
                            "--set", "mesh.resolution=32", "-q"]) == 0
    assert held == {"texture": 0, "variance": 1, "harmonise": 0, "pvm": 0}
    for n in ("texture", "variance", "pvm"):
        out = cache.STAGES[n].outputs[0]
        got, ref = np.load(d2 / "cache" / n / out), np.load(d / "cache" / n / out)
        assert all(np.array_equal(got[k], ref[k]) for k in ref.files), n


def test_holdout_imports_views_as_targets(tmp_path, capsys):
    """--holdout moves input views to the targets at import (ground truth no stage reads); the
    import key follows the list (a new list re-imports); bad lists fail in one line, exit 2."""
    full = native.load(_plain_scene(tmp_path, capsys))
    d = tmp_path / "s"
    out = run(d, "--holdout", "v001", "v002", capsys=capsys)
    assert out["import"]["status"] == "ran" and out["import"]["views"] == 1
    assert out["import"]["targets"] == len(full.targets) + 2
    sc = native.load(d)
    assert [v.name for v in sc.views] == ["v000"] and [t.name for t in sc.targets][-2:] == ["v001", "v002"]
    assert sc.stages["import"]["held_out"] == ["v001", "v002"]
    held = sc.target("v001")
    assert held.has_color and held.has_depth
    np.testing.assert_array_equal(held.color, full.view("v001").color)
    np.testing.assert_array_equal(held.depth, full.view("v001").depth)
    assert run(d, "--holdout", "v001", "v002", capsys=capsys)["import"]["status"] == "up to date"
    assert run(d, "--holdout", "v002", capsys=capsys)["import"]["status"] == "ran"
    assert [v.name for v in native.load(d).views] == ["v000", "v001"]
    for argv, msg in ((["--holdout", "nope"], "no input view named nope"),
                      (["--holdout", "v000", "v001", "v002"], "every input view is held out"),
                      (["--holdout", "t000"], "no input view named t000"),
                      (["--frames", "2", "--holdout", "v000"], "not for a video scene")):
        assert preprocess.main(["synth:objects", "-o", str(tmp_path / "bad"), *SMALL, *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0], err
    assert preprocess.main([str(d), "-o", str(d), "--holdout", "v000"]) == 2
    assert "only when importing" in capsys.readouterr().err


def _plain_scene(tmp_path, capsys):
    d = tmp_path / "plain"
    run(d, capsys=capsys)
    return d


def test_methods_that_need_no_stage_skip_them(built, capsys):
    d, _ = built
    out = run(d, "--methods", "dibr,warp", capsys=capsys)
    for name in ("mesh", "texture", "pvm"):
        assert out[name]["status"] == "skipped" and "not needed by methods dibr, warp" in out[name]["reason"]
    # tm needs no PVM: the PVM stage is skipped, the mesh and texture are up to date.
    out = run(d, "--methods", "tm", capsys=capsys)
    assert out["pvm"]["status"] == "skipped" and "not needed" in out["pvm"]["reason"]
    assert out["mesh"]["status"] == "up to date" and out["texture"]["status"] == "up to date"
    # Default methods (those built): today none needs a derived stage.
    out = run(d, capsys=capsys)
    assert all(out[n]["status"] == "skipped" for n in ("mesh", "texture", "pvm"))


def test_missing_or_corrupt_output_is_rebuilt(built, capsys):
    d, _ = built
    f = d / "cache" / "texture" / "texture.npz"
    f.write_bytes(f.read_bytes()[:-10] + b"0123456789")
    out = run(d, "--methods", "tm", capsys=capsys)
    assert out["texture"]["status"] == "ran" and "missing or corrupt" in out["texture"]["reason"]
    assert out["mesh"]["status"] == "up to date"
    f.unlink()
    out = run(d, "--methods", "tm", capsys=capsys)
    assert out["texture"]["status"] == "ran" and "missing or corrupt" in out["texture"]["reason"]
    assert f.is_file()
    assert run(d, "--methods", "tm", capsys=capsys)["texture"]["status"] == "up to date"


def test_parameter_change_reruns_that_stage_only(built, capsys):
    d, _ = built
    out = run(d, "--stages", "pvm", "--set", "pvm.max_block=8", capsys=capsys)
    assert out["pvm"]["status"] == "ran" and "changed" in out["pvm"]["reason"]
    # pvm reads depth, depth reads the mesh: the mesh is up to date (same parameters).
    assert out["mesh"]["status"] == "up to date"
    assert out["texture"]["status"] == "skipped" and "not selected" in out["texture"]["reason"]
    out = run(d, "--stages", "pvm", "--set", "pvm.max_block=8", capsys=capsys)
    assert out["pvm"]["status"] == "up to date"
    # --force reruns the selected stages.
    out = run(d, "--stages", "pvm", "--set", "pvm.max_block=8", "--force", capsys=capsys)
    assert out["pvm"]["status"] == "ran" and "forced" in out["pvm"]["reason"]
    out = run(d, "--stages", "pvm", "--set", "pvm.mesh_snap=0", capsys=capsys)
    assert out["pvm"]["status"] == "ran" and out["pvm"]["snap"] == "off"
    # Back to the default parameters for the other tests.
    assert run(d, "--stages", "pvm", capsys=capsys)["pvm"]["status"] == "ran"


def test_a_native_scene_is_preprocessed_in_place(built, tmp_path, capsys):
    # `ibr-preprocess SCENE -o SCENE --stages S`: what the renderers' error messages say to run.
    d, _ = built
    (d / "cache" / "texture" / "texture.npz").unlink(missing_ok=True)
    assert preprocess.main([str(d), "-o", str(d), "--stages", "texture", "--set", "mesh.resolution=32",
                            "--json"]) == 0
    out = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}
    assert out["import"]["status"] == "up to date" and "in place" in out["import"]["reason"]
    assert out["texture"]["status"] == "ran" and out["mesh"]["status"] == "up to date", out
    # A directory that holds no scene cannot be its own input.
    (tmp_path / "empty").mkdir()
    assert preprocess.main([str(tmp_path / "empty"), "-o", str(tmp_path / "empty")]) != 0
    err = capsys.readouterr().err
    assert "output is the input" in err and "scene.json" in err
    assert not (tmp_path / "empty" / "scene.json").exists()


def test_changed_scene_content_reruns_derived_stages(tmp_path, capsys):
    d = tmp_path / "s"
    run(d, "--methods", "pvm", capsys=capsys)
    # Edit a view's depth by hand: the scene content hash changes, the stages rerun.
    from ibrtools.imageio import read_depth, write_depth

    f = d / "images" / "v000.depth.exr"
    depth = read_depth(f)
    write_depth(f, depth * np.float32(1.01))
    out = run(d, "--methods", "pvm", capsys=capsys)
    assert out["import"]["status"] == "up to date"
    assert out["mesh"]["status"] == "ran" and out["pvm"]["status"] == "ran"


def test_views_without_depth_get_depth_from_the_mesh(tmp_path, capsys):
    # A native scene whose views have colour only and whose mesh is given: the depth stage runs.
    v = np.array([[-3, -3, 2], [3, -3, 2], [3, 3, 2], [-3, 3, 2]], np.float32)
    mesh = Mesh(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), kind="reconstructed")
    views = []
    for i, x in enumerate((-0.2, 0.2)):
        c = Camera.pinhole(32, 24, 24.0, 24.0, 16.0, 12.0, look_at((x, 0, 0), (x, 0, 2), up=(0, -1, 0)))
        views.append(View.create(f"v{i}", c, color=np.full((24, 32, 3), 0.5, np.float32)))
    src = tmp_path / "src"
    native.save(Scene(views=views, meshes={"reconstructed": mesh}), src)
    d = tmp_path / "s"
    assert preprocess.main([str(src), "-o", str(d), "--methods", "pvm", "--set", "mesh.resolution=16",
                            "--json"]) == 0
    out = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}
    assert out["mesh"]["status"] == "ran" and out["mesh"]["source"] == "reconstructed"
    assert out["depth"]["status"] == "ran" and out["depth"]["views"] == 2
    assert out["pvm"]["status"] == "ran" and out["pvm"]["pvm_faces"] > 0
    dep = cache.load_npz(d / "cache" / "depth" / "depth.npz")
    np.testing.assert_allclose(dep["v0"][dep["v0"] > 0], 2.0, rtol=1e-4)  # plane z = 2 seen head on
    # The PVM renderer's free-space count reads the same depth the PVMs were built from.
    from ibrtools.hybrid.pvm_render import PvmRenderer, load_depths

    scene = native.load(d)
    depths = load_depths(scene)
    assert depths is not None and set(depths) == {"v0", "v1"}
    np.testing.assert_array_equal(depths["v0"], dep["v0"])
    assert PvmRenderer(scene).free_space
    # And without a mesh and without depth: a clear error, exit 2.
    native.save(Scene(views=views), tmp_path / "src2")
    assert preprocess.main([str(tmp_path / "src2"), "-o", str(tmp_path / "s2"), "--methods", "pvm"]) == 2
    # (the mvs stage runs first: these uniform grey photographs match nowhere)
    assert "multi-view stereo matched no pixel" in capsys.readouterr().err


@pytest.mark.parametrize("argv, msg", [
    (["--methods", "magic"], "--methods"),
    (["--stages", "nope"], "--stages"),
    (["--set", "pvm.max_block"], "STAGE.KEY=VALUE"),
    (["--set", "nostage.x=1"], "unknown stage"),
    (["--set", "pvm.max_block=6"], "power of two"),
    (["--set", "pvm.bogus=1"], "bogus"),
    (["--set", "mesh.source=magic"], "mesh source"),
    (["--set", "mix.view=3"], "unknown parameter(s) ['view']"),
    (["--set", "mix.views=0"], "mix.views=0"),
    (["--set", "mix.tol_db=-1"], "mix.tol_db=-1"),
    (["--exposure-jitter", "-1"], "--exposure-jitter"),
    (["--wb-jitter", "-0.5"], "--wb-jitter"),
])
def test_bad_stage_arguments(tmp_path, capsys, argv, msg):
    d = tmp_path / "s"
    assert preprocess.main(["synth:objects", "-o", str(d), "--views", "2", "--size", "32x24", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1
    assert not d.exists()  # arguments are checked before any work


def test_jitter_options_reach_the_synthetic_scene(tmp_path, capsys):
    d = tmp_path / "s"
    assert preprocess.main(["synth:objects", "-o", str(d), "--views", "2", "--size", "32x24",
                            "--exposure-jitter", "0.2", "-q"]) == 0
    src = json.loads((d / "scene.json").read_text())["source"]
    assert src["color_jitter"]["exposure_sigma"] == 0.2


def test_stage_output_for_the_render_methods(built, tmp_path):
    d, _ = built
    from ibrtools.errors import MissingFileError
    from ibrtools.hybrid.pvm import PvmTiles

    f = cache.stage_output(d, "pvm")
    assert f.name == "tiles.npz" and PvmTiles.load(f).num_tiles > 0
    with pytest.raises(MissingFileError, match="no output of stage 'depth'"):
        cache.stage_output(d, "depth")  # skipped: every view has depth
    with pytest.raises(BadValueError, match="unknown"):
        cache.stage_output(d, "nope")
    with pytest.raises(MissingFileError):
        cache.stage_output(tmp_path, "pvm")


def test_outputs_are_hashed_only_when_their_recorded_size_or_time_changed(built, monkeypatch, capsys):
    d, _ = built
    rec = json.loads((d / "scene.json").read_text())["stages"]["pvm"]
    f = d / "cache" / "pvm" / "tiles.npz"
    st = f.stat()
    assert rec["stat"]["tiles.npz"] == [st.st_size, st.st_mtime_ns]
    hashed = []
    real = cache.file_hash
    monkeypatch.setattr(cache, "file_hash", lambda p: hashed.append(p) or real(p))
    assert cache.stage_output(d, "pvm") == f and hashed == []  # as recorded: not read
    assert run(d, "--methods", "pvm", capsys=capsys)["pvm"]["status"] == "up to date"
    assert f not in hashed  # (the inputs are hashed: the scene's content key)
    hashed.clear()
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))  # touched (or copied): hashed, still intact
    assert cache.stage_output(d, "pvm") == f and hashed == [f]
    # ibr-preprocess finds it intact by its hash and records the new time: not hashed again.
    assert run(d, "--methods", "pvm", capsys=capsys)["pvm"]["status"] == "up to date"
    hashed.clear()
    assert cache.stage_output(d, "pvm") == f and hashed == []


def test_failed_stage_leaves_no_record_and_reruns(tmp_path, capsys, monkeypatch):
    d = tmp_path / "s"
    run(d, "--methods", "pvm", capsys=capsys)
    before = json.loads((d / "scene.json").read_text())["stages"]["pvm"]

    def boom(ctx):
        raise RuntimeError("disk full")

    monkeypatch.setitem(S._RUN, "pvm", boom)
    assert preprocess.main(["synth:objects", "-o", str(d), *SMALL, "--stages", "pvm", "--force"]) == 1
    assert "disk full" in capsys.readouterr().err
    doc = json.loads((d / "scene.json").read_text())
    assert "pvm" not in doc["stages"] and "mesh" in doc["stages"]  # no record naming a stale output
    assert not list((d / "cache" / "pvm").glob(".*"))  # no temporary file left behind
    monkeypatch.undo()
    out = run(d, "--methods", "pvm", capsys=capsys)
    assert out["pvm"]["status"] == "ran" and out["pvm"]["tiles"] == before["details"]["tiles"]


def _edit_record(d, stage, **change):
    doc = json.loads((d / "scene.json").read_text())
    rec = doc["stages"][stage]
    for k, v in change.items():
        if v is None:
            rec.pop(k, None)
        else:
            rec[k] = v
    (d / "scene.json").write_text(json.dumps(doc))


def test_out_of_date_stages_are_named_by_preprocess_render_and_bench(tmp_path, capsys):
    from ibrtools_cli import bench, render

    d = tmp_path / "s"
    run(d, "--methods", "pvm", capsys=capsys)
    recs = json.loads((d / "scene.json").read_text())["stages"]
    assert recs["pvm"]["version"] == cache.STAGES["pvm"].version
    assert recs["pvm"]["inputs"] == {"scene": recs["mesh"]["inputs"]["scene"], "mesh": recs["mesh"]["key"],
                                     "depth": "not needed"}  # every view has depth: the depth stage is skipped
    assert all(cache.stale_reasons(recs, n) == [] for n in ("mesh", "pvm"))
    # The mesh alone re-made (another resolution): the pvm stage's tiles are of the previous mesh.
    out = run(d, "--stages", "mesh", "--set", "mesh.resolution=24", capsys=capsys)
    assert out["mesh"]["status"] == "ran"
    assert "not selected" in out["pvm"]["reason"] and "out of date (stage 'mesh' re-ran after it)" in out["pvm"]["reason"]
    assert render.main([str(d), "--method", "pvm", "-o", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "warning: the output of stage pvm (stage 'mesh' re-ran after it) is out of date" in err
    assert f"run ibr-preprocess {d} -o {d} --methods pvm" in err
    assert "re-ran" in json.loads((tmp_path / "r" / "report.json").read_text())["stale_note"]
    # -q prints nothing but errors; the report still says it.
    assert render.main([str(d), "--method", "pvm", "-o", str(tmp_path / "rq"), "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert "re-ran" in json.loads((tmp_path / "rq" / "report.json").read_text())["stale_note"]
    assert bench.main([str(d), "--method", "pvm", "--sweep", "sigma=3", "-o", str(tmp_path / "b"), "--json"]) == 0
    assert "stage pvm" in json.loads(capsys.readouterr().out)["stale_note"]
    # A record of another version of the stage's code; a render method that reads no stale stage says nothing.
    _edit_record(d, "pvm", version=cache.STAGES["pvm"].version - 1)
    why = cache.stale_reasons(json.loads((d / "scene.json").read_text())["stages"], "pvm")
    assert why[0] == f"written by version {cache.STAGES['pvm'].version - 1} of its code, this build's is " \
                     f"{cache.STAGES['pvm'].version}" and len(why) == 2
    assert render.main([str(d), "--method", "dibr", "-o", str(tmp_path / "r2"), "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    # The mesh back at its first resolution: the tiles are of that mesh, so the pvm stage is up to date
    # again (its key matches) and its record is rewritten with this run's version and inputs.
    out = run(d, "--methods", "pvm", capsys=capsys)
    assert out["mesh"]["status"] == "ran" and out["pvm"]["status"] == "up to date"
    assert cache.stale_reasons(json.loads((d / "scene.json").read_text())["stages"], "pvm") == []
    assert render.main([str(d), "--method", "pvm", "-o", str(tmp_path / "r3"), "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert "stale_note" not in json.loads((tmp_path / "r3" / "report.json").read_text())
    # Records written before they carried the version and input keys: nothing to compare, nothing said;
    # the next ibr-preprocess that finds the stage up to date adds them.
    _edit_record(d, "pvm", version=None, inputs=None)
    assert cache.stale_reasons(json.loads((d / "scene.json").read_text())["stages"], "pvm") == []
    assert run(d, "--methods", "pvm", capsys=capsys)["pvm"]["status"] == "up to date"
    rec = json.loads((d / "scene.json").read_text())["stages"]["pvm"]
    assert rec["version"] == cache.STAGES["pvm"].version and rec["inputs"]["depth"] == "not needed"


def test_progress_on_stderr(tmp_path, capsys):
    d = tmp_path / "s"
    assert preprocess.main(["synth:objects", "-o", str(d), *SMALL, "--methods", "pvm"]) == 0
    err = capsys.readouterr().err
    assert "ibr-preprocess: pvm: running" in err and "ibr-preprocess: mesh: running" in err


def test_parse_helpers():
    from ibrtools_cli.common import parse_methods, parse_stage_options, parse_stages

    assert parse_methods("tm, pvm") == ["tm", "pvm"]
    assert parse_methods("all") == list(cache.ALL_METHODS)
    assert parse_stages("pvm,mesh") == ["pvm", "mesh"]
    assert parse_stage_options(["pvm.max_block=8", "mesh.source=fusion"]) == {
        "pvm": {"max_block": 8}, "mesh": {"source": "fusion"}}
    with pytest.raises(BadValueError):
        parse_methods("")
    with pytest.raises(InputError):
        parse_stage_options(["texture.k_views=3"])
    with pytest.raises(FileNotFoundError):
        cache.scene_content_key(S.Path("/nonexistent-scene"))
