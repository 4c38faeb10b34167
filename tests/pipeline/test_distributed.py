"""Distributed execution on Dask (docs/distributed.md): ibr-render and ibr-preprocess
on a LocalCluster (2 worker processes on loopback) write the same files, bit for bit, as a local
run; a failing frame is reported by name and the others are written; a worker killed mid-job
loses no frame; bad options are one-line errors with exit status 2."""
from __future__ import annotations

import filecmp
import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="dask.distributed is not installed (pip install 'ibrtools[distributed]')")

from ibrtools.pipeline import distributed as D  # noqa: E402
from ibrtools.errors import BadValueError  # noqa: E402
from ibrtools.formats import native  # noqa: E402
from ibrtools.pipeline import job as J  # noqa: E402
from ibrtools.pipeline import plan as planning  # noqa: E402
from conftest import synth_scene_dir  # noqa: E402

SIZE = "64x48"
# Fields that differ between any two runs by nature (times; depthwarp's warp/reference time
# ratio) or say where and how it ran; every other report field must be equal.
TIMES = {"seconds", "threads", "distributed", "reference_over_warp", "stat"}  # stat: file times


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = synth_scene_dir(tmp_path_factory, "--views", "4", "--size", SIZE, name="dist")
    return d


@pytest.fixture(scope="module")
def cluster():
    """One LocalCluster for the module: 2 worker processes, 1 thread each, loopback."""
    import logging

    from distributed import Client, LocalCluster

    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                     dashboard_address=None, silence_logs=logging.ERROR,
                     scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    client = Client(c, set_as_default=False)
    yield c.scheduler_address, client
    client.close()
    c.close()


def _poses(scene_dir: Path, tmp_path: Path, extra: list[dict] = ()) -> Path:
    cam = native.load(scene_dir).views[0].camera.to_dict()
    poses = [dict(cam, name="p_a")] + [dict(e) for e in extra]
    f = tmp_path / "poses.json"
    f.write_text(json.dumps(poses))
    return f


def _strip(doc):
    """A report without the fields that are times (or say where and how it ran)."""
    if isinstance(doc, dict):
        return {k: _strip(v) for k, v in doc.items() if k not in TIMES and not k.endswith("_ms")}
    if isinstance(doc, list):
        return [_strip(v) for v in doc]
    return doc


def _same_outputs(a: Path, b: Path) -> list[str]:
    fa, fb = sorted(p.name for p in a.iterdir()), sorted(p.name for p in b.iterdir())
    assert fa == fb
    assert not [f for f in fa if f.startswith(".")], "temporary files left behind"
    differ = [f for f in fa if f != "report.json" and not filecmp.cmp(a / f, b / f, shallow=False)]
    assert differ == [], f"files differ between the local and the distributed run: {differ}"
    ra, rb = (json.loads((d / "report.json").read_text()) for d in (a, b))
    assert _strip(ra) == _strip(rb)
    return fa


def test_render_matches_local_bit_for_bit(scene_dir, cluster, tmp_path):
    # Held-out view (metrics against ground truth), targets, a pose; holes inpainted; PNG, EXR
    # colour, EXR depth, hole masks: every file byte for byte, every report field but the times.
    poses = _poses(scene_dir, tmp_path)
    kw = {"holdout": ["v001"], "targets": ["t000", "t001"], "poses": str(poses)}
    opts = {"float_out": True, "depth_out": True, "inpaint": "pushpull"}
    local = J.run(planning.plan(native.load(scene_dir), **kw), "dibr", tmp_path / "local", **opts)
    calls = []
    dist = J.run(planning.plan(native.load(scene_dir), **kw), "dibr", tmp_path / "dist", scheduler=cluster[0],
                 progress=lambda i, n, name: calls.append((i, n, name)), **opts)
    files = _same_outputs(tmp_path / "local", tmp_path / "dist")
    assert {"v001.png", "v001.exr", "v001.depth.exr", "p_a.png", "report.json"} <= set(files)
    assert local["failed"] == dist["failed"] == []
    assert dist["distributed"]["workers"] == 2 and dist["distributed"]["tasks"] == 4
    assert dist["threads"] == 1 and dist["summary"]["setup_ms"]  # 1 engine thread per task; the preparation reported
    # Progress as frames complete: 0 at the start, then 1..n (completion order), then n of n.
    done = [c[0] for c in calls]
    assert done == [0, 1, 2, 3, 4, 4] and all(c[1] == 4 for c in calls)
    assert sorted(c[2] for c in calls[1:5]) == sorted(f["name"] for f in local["frames"])


def test_depthwarp_frames_stay_in_order(scene_dir, cluster, tmp_path):
    # depthwarp warps from the previous frame: one task renders every frame, in order.
    job = planning.plan(native.load(scene_dir), poses=str(_poses(scene_dir, tmp_path, [
        dict(native.load(scene_dir).views[1].camera.to_dict(), name="p_b")])))
    J.run(job, "depthwarp", tmp_path / "l2", depth_out=True)
    rep = J.run(job, "depthwarp", tmp_path / "d2", depth_out=True, scheduler=cluster[0])
    assert rep["distributed"]["tasks"] == 1
    _same_outputs(tmp_path / "l2", tmp_path / "d2")


def test_failing_frame_is_reported_and_others_written(scene_dir, cluster, tmp_path):
    # A 4x3 pose cannot be foveated (the steerable pyramid needs more pixels): that frame fails,
    # by name, in report.json "failed"; the other frames are written; the same in both modes.
    cam = native.load(scene_dir).views[0].camera.to_dict()
    tiny = dict(cam, name="p_tiny", width=4, height=3, fx=cam["fx"] / 16, fy=cam["fy"] / 16, cx=2.0, cy=1.5)
    poses = _poses(scene_dir, tmp_path, [tiny])
    reps = {}
    for mode, kw in (("local", {}), ("dist", {"scheduler": cluster[0]})):
        job = planning.plan(native.load(scene_dir), holdout=["v002"], poses=str(poses))
        reps[mode] = J.run(job, "reference", tmp_path / mode, foveate=(0.5, 0.5), **kw)
    for rep in reps.values():
        assert [f["name"] for f in rep["failed"]] == ["p_tiny"]
        assert "steerable" in rep["failed"][0]["error"] or "levels" in rep["failed"][0]["error"]
        assert [f["name"] for f in rep["frames"]] == ["v002", "p_a"]
    files = _same_outputs(tmp_path / "local", tmp_path / "dist")
    assert "p_tiny.png" not in files and "p_a.png" in files


def test_cli_failed_frame_exit_1_one_line(scene_dir, cluster, tmp_path, capsys):
    from ibrtools_cli import render

    cam = native.load(scene_dir).views[0].camera.to_dict()
    tiny = dict(cam, name="p_tiny", width=4, height=3, fx=cam["fx"] / 16, fy=cam["fy"] / 16, cx=2.0, cy=1.5)
    poses = _poses(scene_dir, tmp_path, [tiny])
    out = tmp_path / "o"
    code = render.main([str(scene_dir), "--method", "reference", "--poses", str(poses), "--foveate", "0.5,0.5",
                        "--scheduler", cluster[0], "-o", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "1 of 2 frames failed" in err[0] and "p_tiny" in err[0]
    assert (out / "p_a.png").is_file() and (out / "report.json").is_file()
    assert json.loads((out / "report.json").read_text())["failed"][0]["name"] == "p_tiny"


def test_killed_worker_loses_no_frame(scene_dir, cluster, tmp_path):
    # Kill one worker process (SIGKILL, its pid from client.run) after the first frame is in:
    # its tasks (running, or finished but not yet fetched) are rescheduled and the job completes
    # with every frame, identical to the local run.
    address, client = cluster
    client.wait_for_workers(2, timeout=60)
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    kw = {"path": "orbit"}  # 48 frames
    J.run(planning.plan(native.load(scene_dir), **kw), "reference", tmp_path / "local")
    killed = []

    def progress(i, n, name):
        if i >= 1 and not killed:
            os.kill(victim, signal.SIGKILL)
            killed.append(i)

    rep = J.run(planning.plan(native.load(scene_dir), **kw), "reference", tmp_path / "dist", scheduler=address,
                progress=progress)
    assert killed == [1]
    with pytest.raises(ProcessLookupError):
        os.kill(victim, 0)  # it did die (the nanny starts a new process)
    assert len(rep["frames"]) == 48 and rep["failed"] == []
    _same_outputs(tmp_path / "local", tmp_path / "dist")
    client.wait_for_workers(2, timeout=60)  # the nanny's replacement, for the tests after this one
    assert victim not in client.run(os.getpid).values()


def test_cli_workers_matches_local(scene_dir, tmp_path):
    # --workers 2: the command starts (and stops) its own LocalCluster.
    from ibrtools_cli import render

    base = [str(scene_dir), "--method", "dibr", "--holdout", "v003", "--target", "t002", "--depth", "-q"]
    assert render.main(base + ["-o", str(tmp_path / "local")]) == 0
    assert render.main(base + ["-o", str(tmp_path / "dist"), "--workers", "2"]) == 0
    _same_outputs(tmp_path / "local", tmp_path / "dist")
    rep = json.loads((tmp_path / "dist" / "report.json").read_text())
    assert rep["distributed"]["scheduler"] == "local" and rep["distributed"]["workers"] == 2
    assert rep["threads"] == 1  # one engine thread per worker process of a local cluster


@pytest.mark.parametrize("prog", ["render", "preprocess"])
@pytest.mark.parametrize("argv, msg", [
    (["--workers", "-1"], "--workers: expected a number of worker processes >= 0"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "give one"),
    (["--scheduler", ""], "--scheduler: expected an address"),
])
def test_bad_options_exit_2(scene_dir, tmp_path, capsys, prog, argv, msg):
    from ibrtools_cli import preprocess, render

    if prog == "render":
        code = render.main([str(scene_dir), "-o", str(tmp_path / "o")] + argv)
    else:
        code = preprocess.main([str(scene_dir), "-o", str(tmp_path / "s")] + argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and msg in err[0]
    assert not (tmp_path / "o").exists()


def test_unreachable_scheduler_is_a_quick_error(scene_dir, tmp_path, capsys):
    from ibrtools_cli import render

    t0 = time.monotonic()
    # Port 9 on loopback (discard): nothing listens there in this sandbox.
    code = render.main([str(scene_dir), "--holdout", "v001", "--scheduler", "tcp://127.0.0.1:9",
                        "-o", str(tmp_path / "o")])
    elapsed = time.monotonic() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "cannot connect" in err[0] and "tcp://127.0.0.1:9" in err[0]
    assert elapsed < D.CONNECT_TIMEOUT + 10
    assert not list((tmp_path / "o").glob("*.png"))


def test_library_bad_input(scene_dir, tmp_path):
    job = planning.plan(native.load(scene_dir), holdout=["v001"])
    with pytest.raises(BadValueError, match="workers: expected"):
        J.run(job, "dibr", tmp_path / "a", workers=-1)
    with pytest.raises(BadValueError, match="give one"):
        J.run(job, "dibr", tmp_path / "a", workers=1, scheduler="tcp://127.0.0.1:8786")
    with pytest.raises(BadValueError, match="whole number"):
        J.run(job, "dibr", tmp_path / "a", workers=1.5)
    bare = planning.Job(job.scene, job.frames)  # not made by plan(): the workers could not rebuild it
    with pytest.raises(BadValueError, match="not made by plan"):
        J.run(bare, "dibr", tmp_path / "a", workers=1)
    mem = planning.plan(native.load(scene_dir), holdout=["v001"])
    mem.scene.root = None  # a scene in memory only: the workers cannot load it
    with pytest.raises(BadValueError, match="scene directory"):
        J.run(mem, "dibr", tmp_path / "a", workers=1)
    with pytest.raises(BadValueError):
        with D.open_client(None, 0):
            pass
    assert not (tmp_path / "a").exists()


def test_plan_records_its_arguments(scene_dir, tmp_path):
    poses = _poses(scene_dir, tmp_path)
    os.chdir(tmp_path)
    job = planning.plan(native.load(scene_dir), targets=["t000"], poses="poses.json",
                 lightfield=(2, 2, 0.05, None))
    assert job.spec == {"targets": ["t000"], "holdout": None, "path": None, "path_frames": None,
                        "poses": str(poses.resolve()), "lightfield": [2, 2, 0.05, None]}
    # a generated path: the workers make the same cameras from the spec
    gen = planning.plan(native.load(scene_dir), path="spiral", path_frames=5)
    for job in (job, gen):
        again = planning.plan(native.load(scene_dir), **job.spec)
        assert [f.name for f in again.frames] == [f.name for f in job.frames]
        for a, b in zip(again.frames, job.frames):
            np.testing.assert_array_equal(a.camera.cam_from_world, b.camera.cam_from_world)
            assert a.info == b.info


def _colour_only(scene_dir: Path, dest: Path) -> Path:
    """The scene with its views' depth removed (colour and ground-truth mesh kept): the depth
    stage then renders every view's depth from the mesh."""
    from ibrtools.scene import Scene, View

    s = native.load(scene_dir)
    views = [View.create(v.name, v.camera, color=v.color) for v in s.views]
    native.save(Scene(views=views, meshes=s.meshes, units=s.units), dest)
    return dest


@pytest.mark.parametrize("colour_only", [True, False])
def test_preprocess_matches_local_bit_for_bit(scene_dir, cluster, tmp_path, capsys, colour_only):
    from ibrtools.pipeline import stages as S
    from ibrtools import cache
    from ibrtools_cli import preprocess

    # Colour only: the depth stage renders every view's depth; with depth: the pvm stage snaps it.
    src = _colour_only(scene_dir, tmp_path / "src") if colour_only else scene_dir
    common = [str(src), "--methods", "pvm", "--set", "mesh.resolution=24", "--json"]
    assert preprocess.main(common + ["-o", str(tmp_path / "local")]) == 0
    capsys.readouterr()
    assert preprocess.main(common + ["-o", str(tmp_path / "dist"), "--scheduler", cluster[0]]) == 0
    rows = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["depth"]["status"] == ("ran" if colour_only else "skipped") and rows["pvm"]["status"] == "ran"
    assert (rows["pvm"]["snap"].startswith("not needed") if colour_only else isinstance(rows["pvm"]["snap"], float))
    for stage, f in (("mesh", "mesh.npz"), ("depth", "depth.npz"), ("pvm", "tiles.npz")):
        if not colour_only and stage == "depth":
            continue
        a, b = (tmp_path / d / "cache" / stage / f for d in ("local", "dist"))
        assert filecmp.cmp(a, b, shallow=False), f"{stage}/{f} differs"
    recs = [json.loads((tmp_path / d / "scene.json").read_text())["stages"] for d in ("local", "dist")]
    assert _strip(recs[0]) == _strip(recs[1])
    # Up to date afterwards: no cluster is needed (none is started when no per-view stage runs).
    assert preprocess.main(common + ["-o", str(tmp_path / "dist"), "--workers", "2"]) == 0
    rows = {r["stage"]: r for r in json.loads(capsys.readouterr().out)}
    assert all(r["status"] in ("up to date", "skipped") for r in rows.values())
    cache.stage_output(tmp_path / "dist", "pvm")  # recorded with its hash


def test_mvs_stage_matches_local_bit_for_bit(scene_dir, cluster, tmp_path, capsys):
    """The mvs stage per view on the workers (photometric, then geometric from the cache): the
    same mvs.npz, bit for bit, and the same record but for the times."""
    from conftest import photos_only
    from ibrtools_cli import preprocess

    src = photos_only(scene_dir, tmp_path / "src")

    common = [str(src), "--methods", "dibr", "--set", "mvs.iterations=3", "--set", "mvs.levels=2", "--json"]
    assert preprocess.main(common + ["-o", str(tmp_path / "local")]) == 0
    capsys.readouterr()
    assert preprocess.main(common + ["-o", str(tmp_path / "dist"), "--scheduler", cluster[0]]) == 0
    assert {r["stage"]: r for r in json.loads(capsys.readouterr().out)}["mvs"]["status"] == "ran"
    a, b = (tmp_path / d / "cache" / "mvs" / "mvs.npz" for d in ("local", "dist"))
    assert filecmp.cmp(a, b, shallow=False), "mvs.npz differs"
    assert sorted(p.name for p in b.parent.iterdir()) == ["mvs.npz"]  # the passes' exchange file is gone
    recs = [json.loads((tmp_path / d / "scene.json").read_text())["stages"]["mvs"] for d in ("local", "dist")]
    for r in recs:
        r["details"].pop("seconds")
        r["details"].pop("evaluations_per_second")
    assert _strip(recs[0]) == _strip(recs[1])


def test_local_workers_drop_only_the_lost_heartbeat(cluster):
    # A local cluster's shutdown can cut off a worker's heartbeat: its traceback is dropped in
    # the worker (the plugin open_client registers), every other worker record passes.
    import logging

    _, client = cluster
    client.register_plugin(D._ignore_sigint_plugin(), name="ibrtools-ignore-sigint")

    def passes(msg: str) -> bool:
        rec = logging.LogRecord("distributed.worker", logging.ERROR, __file__, 1, msg, None, None)
        return bool(logging.getLogger("distributed.worker").filter(rec))

    for verdicts in client.run(lambda: [passes(D.HEARTBEAT_LOST), passes("Compute Failed")]).values():
        assert verdicts == [False, True]


def test_client_loop_drops_only_dasks_cancel_before_start():
    # dask's sync() answers Ctrl-C with a cancel callback that can raise NameError on the loop
    # thread (its future not assigned yet): that record is dropped while a client is in use.
    import logging
    import sys

    def record_of(fn) -> logging.LogRecord:
        try:
            fn()
        except NameError:
            info = sys.exc_info()
        return logging.LogRecord("tornado.application", logging.ERROR, __file__, 1, "Exception in callback",
                                 None, info)

    def defined_in(filename: str):
        ns: dict = {}
        exec(compile("def cancel():\n    return undefined_future\n", filename, "exec"), ns)
        return ns["cancel"]

    dask_bug = record_of(defined_in("/site-packages/distributed/utils.py"))
    elsewhere = record_of(defined_in("/site-packages/other/utils.py"))
    log = logging.getLogger("tornado.application")
    flag = [False]
    with D._note_interrupt(flag):
        assert not log.filter(dask_bug)
        assert log.filter(elsewhere)
        assert log.filter(logging.LogRecord("tornado.application", logging.ERROR, __file__, 1, "x", None, None))
    assert log.filter(dask_bug) and not flag[0]  # only while the client is in use


def test_lazy_client_starts_nothing_unused():
    with D.LazyClient(None, 3) as lc:
        assert lc._client is None and lc.task_threads == 0  # 0: the default, one engine thread per task
    with pytest.raises(BadValueError):
        D.LazyClient(None, -2)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupted_distributed_render_leaves_nothing(scene_dir, tmp_path, sig):
    # All or nothing as a local run: interrupted once frames are written (SIGINT to the whole
    # process group, as Ctrl-C in a terminal does; SIGTERM to the command alone), the command
    # exits 130 / 143, removes every file it wrote and stops its workers.
    import subprocess
    import sys

    from procs import interruptible

    cam = native.load(scene_dir).views[0].camera.to_dict()
    s = 160 / cam["width"]
    cam.update(width=160, height=120, fx=cam["fx"] * s, fy=cam["fy"] * s, cx=cam["cx"] * s, cy=cam["cy"] * s)
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps([dict(cam, name=f"f{i:04d}") for i in range(2000)]))
    out = tmp_path / "out"
    argv = [sys.executable, "-c", "import sys; from ibrtools_cli.render import main; sys.exit(main())",
            str(scene_dir), "--method", "dibr", "--poses", str(poses), "--workers", "2", "-o", str(out), "-q"]
    # SIGINT at its default action in the command even when this test inherited it ignored
    # (a background job): tests/procs.py.
    proc = subprocess.Popen(interruptible(argv), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        t0 = time.monotonic()
        while not (out / "f0003.png").exists():
            assert proc.poll() is None, proc.stderr.read().decode()[-800:]
            assert time.monotonic() - t0 < 120, "no frame written after 120 s"
            time.sleep(0.05)
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = proc.stderr.read().decode()
    assert code == {signal.SIGINT: 130, signal.SIGTERM: 143}[sig], err[-800:]
    left = sorted(p.name for p in out.iterdir()) if out.exists() else []
    assert not left, f"interrupted render left {left[:8]}"
    assert "Traceback" not in err  # the workers ignore SIGINT: no worker's traceback on the terminal
    # No worker process of the command's survives it: its process group empties (an exited
    # worker is reaped by init a moment later).
    t0 = time.monotonic()
    while time.monotonic() - t0 < 20:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        pytest.fail("worker processes of the interrupted command are still running after 20 s")


def test_missing_dask_is_a_clear_error(monkeypatch, scene_dir, tmp_path, capsys):
    import sys

    from ibrtools_cli import render

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(D.MissingDaskError, match=r"ibrtools\[distributed\]"):
        with D.open_client(None, 2):
            pass
    assert render.main([str(scene_dir), "--holdout", "v001", "--workers", "2", "-o", str(tmp_path / "o")]) == 2
    assert "needs dask.distributed" in capsys.readouterr().err
    assert not list((tmp_path / "o").glob("*.png"))
