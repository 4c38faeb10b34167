"""Memory limits: a render job whose estimate exceeds the available memory
fails before anything is allocated, with a message that says how much it needs and why.
The peak figures the estimate is calibrated on are in docs/robustness.md (tools/measure_memory.py)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from ibrtools import BadValueError, Camera, Scene, View, look_at
from ibrtools import memory
from ibrtools.pipeline import job as render_job
from ibrtools.pipeline import plan as planning
from conftest import synth_scene_dir
SIZE = "48x36"


def _never(what):
    def load():
        raise AssertionError(f"{what} was loaded: the memory check must run before any image is read")
    return load


def huge_job(n_views=64, side=16384):
    """64 input views of 16K x 16K and a 16K target, images never loaded (loaders assert)."""
    views = []
    for i in range(n_views):
        a = 2 * np.pi * i / n_views
        cam = Camera.pinhole(side, side, side, side, side / 2, side / 2,
                             look_at([3 * np.cos(a), 0.5, 3 * np.sin(a)], [0, 0, 0]))
        views.append(View.create(f"v{i:03d}", cam, color=_never(f"v{i:03d} colour"), depth=_never(f"v{i:03d} depth")))
    target = View.create("t", Camera.pinhole(side, side, side, side, side / 2, side / 2, look_at([0, 0.5, 3], [0, 0, 0])))
    scene = Scene(views=views, targets=[target], paths={}, units="m", source={"format": "test"})
    return planning.plan(scene)


@pytest.mark.parametrize("method", ["dibr", "warp"])
def test_16k_by_64_views_fails_early_with_a_clear_message(tmp_path, method, monkeypatch):
    monkeypatch.delenv("IBR_MEMORY_LIMIT", raising=False)
    job = huge_job()
    est = planning.estimate_memory(job, method)
    # 64 x 16384^2 pixels of colour + depth alone are 64 x 1 GiB x 4 = 256 GiB: the estimate is above it
    assert est["inputs"] >= 64 * 16384 ** 2 * 16
    t0 = time.perf_counter()
    with pytest.raises(BadValueError) as e:
        render_job.run(job, method, tmp_path / "out")
    assert time.perf_counter() - t0 < 5.0  # early: nothing loaded, nothing rendered (generous bound)
    msg = str(e.value)
    assert "GiB" in msg and "64 input views" in msg and "16384x16384" in msg and "available" in msg
    assert not (tmp_path / "out").exists()  # no output directory made for a refused job


def test_estimate_scales_and_reference_ignores_views():
    small, big = huge_job(n_views=2, side=64), huge_job(n_views=8, side=64)
    a, b = planning.estimate_memory(small, "dibr"), planning.estimate_memory(big, "dibr")
    assert b["inputs"] == 4 * a["inputs"] and b["frame"] == a["frame"]
    assert planning.estimate_memory(big, "reference")["inputs"] == 0  # reference reads the mesh only


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = synth_scene_dir(tmp_path_factory, "--views", "3", "--size", SIZE, name="mem")
    return d


def test_limit_from_environment(scene_dir, tmp_path, monkeypatch):
    from ibrtools.formats import native

    job = planning.plan(native.load(scene_dir), holdout=["v001"])
    monkeypatch.setenv("IBR_MEMORY_LIMIT", "1M")
    with pytest.raises(BadValueError, match=r"IBR_MEMORY_LIMIT"):
        render_job.run(job, "dibr", tmp_path / "a")
    monkeypatch.setenv("IBR_MEMORY_LIMIT", "64G")
    rep = render_job.run(job, "dibr", tmp_path / "b")
    assert len(rep["frames"]) == 1
    for bad in ("lots", "-3G", "0"):
        monkeypatch.setenv("IBR_MEMORY_LIMIT", bad)
        with pytest.raises(BadValueError, match="IBR_MEMORY_LIMIT"):
            memory.available_memory()


def test_available_memory_reads_the_system(monkeypatch):
    monkeypatch.delenv("IBR_MEMORY_LIMIT", raising=False)
    avail = memory.available_memory()
    assert 0 < avail  # /proc/meminfo on Linux; "unknown" elsewhere is a huge number, never 0


def test_cli_refuses_with_one_line_and_exit_2(scene_dir, tmp_path, capsys, monkeypatch):
    from ibrtools_cli import render

    monkeypatch.setenv("IBR_MEMORY_LIMIT", "1M")
    code = render.main([str(scene_dir), "--method", "dibr", "--holdout", "v001", "-o", str(tmp_path / "o"), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and "GiB" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
