"""Where a job writes: frame names from scenes and pose files never escape the output
directory, a render never writes into a scene, an output directory is held by one job at a
time, a job cleans only its own temporaries, what a killed job left is swept and said, and
files get the umask's mode (ibrtools.outputs; docs/robustness.md "Hostile and careless input")."""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import synth_scene_dir

SIZE = "160x120"


def _cli(prog: str) -> list[str]:
    return [sys.executable, "-c", f"import sys; from ibrtools_cli.{prog} import main; sys.exit(main())"]


def _tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` with its content hash (what "nothing changed" compares)."""
    return {str(p.relative_to(root)): hashlib.blake2b(p.read_bytes(), digest_size=8).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "4", "--size", SIZE, name="hostile")


def _pose(scene_dir: Path, name) -> dict:
    from ibrtools.formats import native

    cam = native.load(scene_dir).views[0].camera.to_dict()
    return dict(cam, name=name)


def _render(scene_dir: Path, out: Path, *args: str) -> int:
    from ibrtools_cli import render

    return render.main([str(scene_dir), "--method", "dibr", "-o", str(out), "-q", *args])


@pytest.mark.parametrize("name", ["../victim", "/abs/victim", "a/../../victim", "..", ".hidden", "x\\y", "t\x01"])
def test_pose_names_never_escape_the_output(scene_dir, tmp_path, name):
    """The issue's repro: a pose named "../victim" wrote victim.png beside -o (exit 0). Now the
    name is mapped to one plain file name inside -o and the report says so."""
    poses = tmp_path / "p.json"
    poses.write_text(json.dumps([_pose(scene_dir, name)]))
    work = tmp_path / "w"
    out = work / "o" / "x"
    before = _tree(scene_dir)
    assert _render(scene_dir, out, "--poses", str(poses)) == 0
    outside = [p for p in tmp_path.rglob("*") if p.is_file() and out not in p.parents and p != poses]
    assert outside == [], f"written outside -o: {outside}"
    assert not Path("/abs/victim.png").exists()
    rep = json.loads((out / "report.json").read_text())
    image = rep["frames"][0]["image"]
    assert Path(image).name == image and not image.startswith(".")
    assert (out / image).is_file()
    assert rep["frames"][0]["name"] == name
    assert rep["output"]["renamed"] == {name: image.removesuffix(".png")}
    assert _tree(scene_dir) == before


def test_scene_view_names_are_mapped_too(scene_dir, tmp_path):
    """A view named "../victim" in a scene.json, held out: its frame files stay inside -o."""
    import shutil

    s = tmp_path / "s"
    shutil.copytree(scene_dir, s)
    doc = json.loads((s / "scene.json").read_text())
    doc["views"][1]["name"] = "../victim"
    (s / "scene.json").write_text(json.dumps(doc))
    before = _tree(s)
    out = tmp_path / "o"
    assert _render(s, out, "--holdout", "../victim") == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o", "s"]
    assert (out / "_._victim.png").is_file()
    assert _tree(s) == before


def test_frame_names_whose_files_collide_are_refused(scene_dir, tmp_path, capsys):
    poses = tmp_path / "p.json"
    poses.write_text(json.dumps([_pose(scene_dir, "a"), _pose(scene_dir, "a.hole")]))
    out = tmp_path / "o"
    assert _render(scene_dir, out, "--poses", str(poses)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "a.hole.png" in err
    assert not out.exists()


@pytest.mark.parametrize("where", ["images", "targets", ".", "images/deeper", ""])
def test_render_into_the_scene_or_nowhere_is_refused(scene_dir, tmp_path, monkeypatch, capsys, where):
    """-o S/images replaced the input v003.png (the next run scored 61.7 dB against its own
    output); -o "" rendered into the current directory and deleted a report.json there."""
    before = _tree(scene_dir)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "report.json").write_text("{}")
    out = "" if where == "" else str(scene_dir / where)
    assert _render(scene_dir, out, "--holdout", "v001") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ibr-render: error: -o")
    assert ("empty" in err) if where == "" else ("scene" in err)
    assert _tree(scene_dir) == before
    assert (tmp_path / "report.json").read_text() == "{}"


def test_bench_into_the_scene_is_refused(scene_dir, capsys):
    from ibrtools_cli import bench

    before = _tree(scene_dir)
    assert bench.main([str(scene_dir), "--method", "dibr", "--sweep", "inputs=2", "--holdout", "v001",
                       "-o", str(scene_dir / "bench"), "-q"]) == 2
    assert "scene" in capsys.readouterr().err
    assert _tree(scene_dir) == before


def test_a_second_job_in_a_held_directory_is_refused(scene_dir, tmp_path, capsys):
    from ibrtools.outputs import OutputDir

    out = tmp_path / "o"
    with OutputDir(out, "ibr-render other job"):
        assert _render(scene_dir, out, "--holdout", "v001") == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"pid {os.getpid()}" in err and "ibr-render other job" in err
        assert sorted(p.name for p in out.iterdir()) == [".ibr-lock"]
    assert not out.exists()  # the holder created it and wrote nothing: gone with its lock
    assert _render(scene_dir, out, "--holdout", "v001") == 0
    assert not (out / ".ibr-lock").exists()


def test_preprocess_holds_its_scene(tmp_path, capsys):
    from ibrtools.outputs import scene_lock
    from ibrtools_cli import preprocess

    s = tmp_path / "s"
    with scene_lock(s, "ibr-preprocess elsewhere"):
        assert preprocess.main(["synth:objects", "-o", str(s), "--views", "2", "--size", "64x48", "-q"]) == 2
        assert "in use by another job" in capsys.readouterr().err
    assert not s.exists() and sorted(p.name for p in tmp_path.iterdir()) == []


def test_cleanup_and_sweep_touch_only_dead_jobs_temporaries(scene_dir, tmp_path):
    """A live job's temporary (this test process's pid) survives another job's run; a dead
    job's (a pid that no longer exists) and an unmarked temporary of a frame file are swept
    and named in the report."""
    out = tmp_path / "o"
    out.mkdir()
    dead = _dead_pid()
    live = out / f".v001.ibrtmp-{os.getpid()}-abcdef.k2j3.png"
    gone = [out / f".v001.ibrtmp-{dead}-012345.zz9x.png", out / ".v001.abcd_123.png"]
    for f in [live, *gone]:
        f.write_bytes(b"x")
    assert _render(scene_dir, out, "--holdout", "v001") == 0
    assert live.exists() and not any(f.exists() for f in gone)
    rep = json.loads((out / "report.json").read_text())
    assert rep["output"]["swept"] == sorted(f.name for f in gone)


def _dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def test_rerun_says_what_it_replaced_and_removed(scene_dir, tmp_path):
    out = tmp_path / "o"
    assert _render(scene_dir, out, "--holdout", "v001", "v002") == 0
    assert {"v001.png", "v002.png"} <= {p.name for p in out.iterdir()}
    assert _render(scene_dir, out, "--holdout", "v001") == 0
    rep = json.loads((out / "report.json").read_text())
    assert "v001.png" in rep["output"]["replaced"]
    assert "v002.png" in rep["output"]["removed"] and not (out / "v002.png").exists()
    named = {f[k] for f in rep["frames"] for k in ("image", "hole_mask") if k in f}
    assert {p.name for p in out.iterdir()} == named | {"report.json"}


def test_killed_render_is_swept_by_the_next(scene_dir, tmp_path):
    """SIGKILL mid-run: no cleanup can run. The next job in that directory removes the killed
    job's frames (its journal in .ibr-lock) and temporaries, and says so."""
    cam = _pose(scene_dir, "f")
    poses = tmp_path / "many.json"
    poses.write_text(json.dumps([dict(cam, name=f"f{i:04d}") for i in range(400)]))
    out = tmp_path / "o"
    proc = subprocess.Popen(_cli("render") + [str(scene_dir), "--method", "dibr", "--poses", str(poses),
                                              "-o", str(out), "-q", "-j", "1"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (out / "f0003.png").exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        assert (out / "f0003.png").exists(), "the render did not start"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
    left = {p.name for p in out.iterdir()}
    assert ".ibr-lock" in left and "report.json" not in left
    assert _render(scene_dir, out, "--holdout", "v001") == 0
    rep = json.loads((out / "report.json").read_text())
    assert "f0003.png" in rep["output"]["removed"]
    assert {p.name for p in out.iterdir()} - {"v001.hole.png"} == {"v001.png", "report.json"}


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_outputs_get_the_umask_mode(scene_dir, tmp_path, umask):
    """Outputs were 0600 (files) / 0700 (scene directories) whatever the umask."""
    out, s = tmp_path / "o", tmp_path / "s"
    run = dict(capture_output=True, preexec_fn=lambda: os.umask(umask))
    assert subprocess.run(_cli("render") + [str(scene_dir), "--method", "dibr", "--holdout", "v001",
                                            "-o", str(out), "-q"], **run).returncode == 0
    assert subprocess.run(_cli("preprocess") + ["synth:objects", "-o", str(s), "--views", "2",
                                                "--size", "64x48", "-q"], **run).returncode == 0
    for f in [out / "v001.png", out / "report.json", s / "scene.json", *s.glob("images/*")]:
        assert f.stat().st_mode & 0o777 == 0o666 & ~umask, f
    for d in [out, s, s / "images"]:
        assert d.stat().st_mode & 0o777 == 0o777 & ~umask, d


_MODES = """
import os, stat, sys
from pathlib import Path
import numpy as np
from ibrtools.imageio import atomic_path, write_image
from ibrtools.outputs import UMASK, mkdtemp_beside
d = Path(sys.argv[1])
with atomic_path(d / "new" / "a.json") as tmp:
    tmp.write_text("{}")
write_image(d / "new" / "b.png", np.zeros((2, 2, 3), np.float32))
t = mkdtemp_beside(d / "c")
print(oct(UMASK), *(oct(stat.S_IMODE(p.stat().st_mode)) for p in (d / "new" / "a.json", d / "new" / "b.png", t)))
"""


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_atomic_writes_get_the_umask_mode(tmp_path, umask):
    """The one temporary-file writer (ibrtools.outputs.mkstemp_beside, under imageio.atomic_path)
    gives 0666 & ~umask, its directories 0777 & ~umask, the umask read once at import."""
    r = subprocess.run([sys.executable, "-c", _MODES, str(tmp_path)], capture_output=True, text=True,
                       preexec_fn=lambda: os.umask(umask))
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == [oct(umask), oct(0o666 & ~umask), oct(0o666 & ~umask), oct(0o777 & ~umask)]


def test_output_that_cannot_be_written_is_one_line(scene_dir, tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert _render(scene_dir, f / "sub", "--holdout", "v001") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot write into it" in err


# --- fuzzing the pose-file and scene.json loaders (names and values) --------------------------------
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

pytestmark = [pytest.mark.asan]

FUZZ = settings(max_examples=int(os.environ.get("IBR_FUZZ_EXAMPLES", "20")), deadline=None, derandomize=True,
                database=None, suppress_health_check=list(HealthCheck))
_PARTS = ["..", ".", "/", "\\", "\0", "\n", "~", "victim", "report", ".ibr-lock", "a.mask", "é", " ", "*", ":"]
NAMES = st.one_of(st.lists(st.sampled_from(_PARTS), min_size=0, max_size=6).map("".join),
                  st.text(max_size=300), st.integers(), st.none(), st.lists(st.integers(), max_size=2))
NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12),
                    st.sampled_from([0, -1, 1e308, 1e-308, 65536, 1 << 40, "12", "x", None, True]))
FIELDS = ["width", "height", "fx", "fy", "cx", "cy"]


def _outside_and_scene(tmp: Path, out: Path, scene: Path, before: dict, keep: set[Path]) -> None:
    outside = [p for p in tmp.rglob("*") if p.is_file() and out not in p.parents and scene not in p.parents
               and p not in keep]
    assert outside == [], f"written outside -o: {outside}"
    assert _tree(scene) == before, "a file of the scene changed"


@FUZZ
@given(name=NAMES, changes=st.dictionaries(st.sampled_from(FIELDS + ["cam_from_world", "model"]), NUMBERS,
                                            max_size=3), count=st.integers(1, 3))
def test_fuzz_pose_file(scene_dir, tmp_path_factory, name, changes, count):
    tmp = tmp_path_factory.mktemp("fz")
    poses = tmp / "p.json"
    cams = [dict(_pose(scene_dir, name), **changes) for _ in range(count)]
    if count > 1 and isinstance(name, str):
        for i, c in enumerate(cams):
            c["name"] = f"{name}{i}"
    poses.write_text(json.dumps(cams))
    out = tmp / "o" / "x"
    before = _tree(scene_dir)
    code = _render(scene_dir, out, "--poses", str(poses))
    assert code in (0, 2)
    _outside_and_scene(tmp, out, scene_dir, before, {poses})


@FUZZ
@given(name=NAMES, which=st.sampled_from(["views", "targets"]), changes=st.dictionaries(
    st.sampled_from(FIELDS), NUMBERS, max_size=2))
def test_fuzz_scene_json(scene_dir, tmp_path_factory, name, which, changes):
    import shutil

    tmp = tmp_path_factory.mktemp("fz")
    s = tmp / "s"
    shutil.copytree(scene_dir, s)
    doc = json.loads((s / "scene.json").read_text())
    entry = doc[which][0]
    entry["name"] = name
    entry["camera"].update(changes)
    (s / "scene.json").write_text(json.dumps(doc))
    before = _tree(s)
    out = tmp / "o"
    args = ["--holdout", str(name)] if which == "views" else ["--target", str(name)]
    code = _render(s, out, *args)
    assert code in (0, 2)
    _outside_and_scene(tmp, out, s, before, set())
