"""Hostile and careless parameters: every bound is checked before any work, through the
commands' main([...]): exit status 2, one line on stderr naming the argument, nothing written."""
from __future__ import annotations

import pytest

from ibrtools.errors import BadValueError
from ibrtools import methods
from ibrtools_cli import bench, preprocess, render
from conftest import synth_scene_dir


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "4", "--size", "48x36", name="hostile")


def _one_line(capsys, *names: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in names:
        assert n in err, err
    return err


def _tree(d):
    return sorted((str(p.relative_to(d)), p.stat().st_size) for p in d.rglob("*"))


# 1. Every method's numeric parameters have upper bounds, checked by the method's check_params:
# ibr-render refuses them before the scene is read (they failed frame by frame, exit 1, with
# partial output), ibr-bench and the Python API alike.
RENDER_CASES = [
    (["--method", "depthwarp", "--path", "orbit", "--layers", "1000"], "--layers", "<= 16"),
    (["--method", "depthwarp", "--path", "orbit", "--seeds", "100000"], "--seeds", "<= 256"),
    (["--method", "depthwarp", "--path", "orbit", "--iters", "100000"], "--iters", "<= 64"),
    (["--method", "depthwarp", "--path", "orbit", "--param", "threshold=1e9"], "--param threshold", "1e+06"),
    (["--method", "dibr", "--holdout", "v001", "--blend-exponent", "100"], "--blend-exponent", "<= 16"),
    (["--method", "dibr", "--holdout", "v001", "--param", "samples=100000000"], "--param samples", "<= 100000"),
    (["--method", "warp", "--holdout", "v001", "--param", "stretch_threshold=1e30"], "--param stretch_threshold",
     "1e+06"),
    (["--method", "reference", "--holdout", "v001", "--param", "ambient=1e40"], "--param ambient", "1e+06"),
    (["--method", "ulr", "--holdout", "v001", "--param", "k=65"], "--param k", "<= 64"),
    (["--method", "pvm", "--holdout", "v001", "--param", "ulr_k=1000"], "--param ulr_k", "<= 64"),
]
if "hybrid" in methods.BUILT:
    RENDER_CASES.append((["--method", "hybrid", "--holdout", "v001", "--param", "tau_var=1e300"], "--param tau_var",
                         "1e+06"))


@pytest.mark.parametrize("argv, flag, bound", RENDER_CASES)
def test_render_refuses_out_of_bound_parameters_before_any_work(scene_dir, tmp_path, capsys, argv, flag, bound):
    out = tmp_path / "out"
    assert render.main([str(scene_dir), *argv, "-o", str(out)]) == 2
    _one_line(capsys, f"ibr-render: error: {flag}", bound)
    assert not out.exists()


def test_bench_and_python_api_share_the_bounds(scene_dir, tmp_path, capsys):
    out = tmp_path / "sweep"
    assert bench.main([str(scene_dir), "--method", "depthwarp", "--sweep", "layers=2:1000", "-o", str(out)]) == 2
    _one_line(capsys, "ibr-bench: error: --sweep layers", "<= 16")
    assert not out.exists()
    for name, params in (("depthwarp", {"layers": 17}), ("depthwarp", {"seeds": 257}), ("dibr", {"blend_exponent": 17})):
        with pytest.raises(BadValueError):
            methods.create(name, params)
    methods.create("depthwarp", {"layers": 16, "seeds": 256, "iters": 64})  # the bounds themselves are accepted


# 2. The mesh stage: an absolute bound on the resolution, and TSDF fusion's memory estimate checked
# before the grid is allocated (IBR_MEMORY_LIMIT small: no real huge allocation).
def test_mesh_resolution_bound_and_fusion_memory_estimate(scene_dir, capsys, monkeypatch):
    before = _tree(scene_dir)
    base = [str(scene_dir), "-o", str(scene_dir), "--methods", "tm", "-q"]
    for res in ("20000", "100000"):
        assert preprocess.main([*base, "--set", f"mesh.resolution={res}"]) == 2
        _one_line(capsys, f"--set mesh.resolution={res}", "<= 4096")
    monkeypatch.setenv("IBR_MEMORY_LIMIT", "64M")
    # without -q too: the refusal comes before the stage's progress line
    assert preprocess.main([*base[:-1], "--set", "mesh.source=fusion", "--set", "mesh.resolution=1000"]) == 2
    err = _one_line(capsys, "--set mesh.resolution=1000", "TSDF fusion needs about", "IBR_MEMORY_LIMIT")
    assert "GiB" in err
    assert _tree(scene_dir) == before


def test_fusion_memory_grows_with_the_surface(scene_dir):
    from ibrtools.formats import native
    from ibrtools.hybrid.globalmesh import FUSION_BLOCK_BYTES, GlobalMeshOptions, fusion_memory

    s = native.load(scene_dir)
    cams, deps = {v.name: v.camera for v in s.views}, {v.name: v.fusion_depth for v in s.views}
    lo, hi = (fusion_memory(cams, deps, GlobalMeshOptions(resolution=r)) for r in (64, 512))
    assert 0 < lo["blocks"] < hi["blocks"] <= sum(int((d > 0).sum()) for d in deps.values())
    assert hi["total"] - lo["total"] == (hi["blocks"] - lo["blocks"]) * FUSION_BLOCK_BYTES


# 3. --set: an unknown key lists the stage's keys; a value of the wrong type names the --set.
@pytest.mark.parametrize("setting, names", [
    ("mesh.nosuch=3", ("--set mesh.nosuch", "unknown parameter of stage 'mesh'", "resolution, trunc_voxels")),
    ("pvm.nosuch=3", ("--set pvm.nosuch", "max_block")),
    ("mesh.resolution=abc", ("--set mesh.resolution=abc", "expected an integer")),
    ("mesh.k_views=1000", ("--set mesh.k_views=1000", "<= 64")),
    ("pvm.coarse=4096", ("--set pvm.coarse=4096", "<= 256")),
])
def test_stage_options_one_line(scene_dir, capsys, setting, names):
    before = _tree(scene_dir)
    assert preprocess.main([str(scene_dir), "-o", str(scene_dir), "--methods", "tm,pvm", "--set", setting]) == 2
    _one_line(capsys, "ibr-preprocess: error:", *names)
    assert _tree(scene_dir) == before


# 4. argparse's usage errors: one line and "see PROG --help", exit 2 (was the 11-line usage block).
@pytest.mark.parametrize("main, prog, argv, names", [
    (render.main, "ibr-render", ["x", "--method", "magic"], ("argument --method: invalid choice: 'magic'",)),
    (preprocess.main, "ibr-preprocess", ["synth:objects", "-o", "x", "--size", "0x5"], ("argument --size",)),
    (preprocess.main, "ibr-preprocess", ["synth:objects"], ("-o/--output",)),
    (bench.main, "ibr-bench", ["x", "-o", "y", "--report-frames", "many"], ("argument --report-frames",)),
])
def test_usage_errors_are_one_line(capsys, main, prog, argv, names):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = _one_line(capsys, f"{prog}: error: ", *names)
    assert err.endswith(f"; see {prog} --help")


# 5. Synthetic scenes: --size, --views and --frames bounded, and their memory estimated.
@pytest.mark.parametrize("argv, names", [
    (["--size", "100000x100000"], ("--size", "at most 16384")),
    (["--size", "16000x16000"], ("--size", "needs about", "GiB")),
    (["--views", "100000"], ("--views", "<= 4096")),
    (["--frames", "5000"], ("--frames", "<= 1000")),
])
def test_synthetic_scene_size_bounded(tmp_path, capsys, argv, names):
    out = tmp_path / "s"
    assert preprocess.main(["synth:objects", "-o", str(out), *argv]) == 2
    _one_line(capsys, "ibr-preprocess: error:", *names)
    assert not out.exists()


def test_synthetic_scene_memory_limit(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("IBR_MEMORY_LIMIT", "100M")
    out = tmp_path / "s"
    assert preprocess.main(["synth:objects", "-o", str(out), "--views", "4", "--size", "48x36"]) == 2
    _one_line(capsys, "--size", "IBR_MEMORY_LIMIT")
    assert not out.exists()


def test_render_lightfield_grid_bounded(scene_dir, tmp_path, capsys):
    out = tmp_path / "lf"
    assert render.main([str(scene_dir), "--lightfield", "100000x100000", "--baseline", "0.1", "-o", str(out)]) == 2
    _one_line(capsys, "--lightfield")
    assert not out.exists()
