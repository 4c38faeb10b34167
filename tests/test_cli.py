"""The commands end to end on a tiny synthetic scene: stage table, report.json contract,
exit codes and one-line errors for bad input, nothing half-written."""
import argparse
import json
import pickle
import subprocess
import sys

import numpy as np
import pytest

from ibrtools.errors import BadValueError, InputError, MissingFileError, NotBuiltError, ParamError
from ibrtools_cli import bench, preprocess, render
from ibrtools_cli.common import error_line
from conftest import synth_scene_dir

SIZE = "64x48"


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "6", "--size", SIZE, name="cli")


def test_preprocess_prints_stage_table_then_is_up_to_date(scene_dir, capsys):
    assert preprocess.main(["synth:objects", "-o", str(scene_dir), "--views", "6", "--size", SIZE,
                            "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["stage"] == "import" and rows[0]["status"] == "up to date"
    assert preprocess.main(["synth:objects", "-o", str(scene_dir), "--views", "6", "--size", SIZE]) == 0
    out = capsys.readouterr().out
    assert "up to date" in out and "nothing to do" in out


def test_preprocess_changed_parameters_rerun(tmp_path, capsys):
    d = tmp_path / "s"
    assert preprocess.main(["synth:objects", "-o", str(d), "--views", "2", "--size", "32x24", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)[0]["status"] == "ran"
    assert preprocess.main(["synth:objects", "-o", str(d), "--views", "3", "--size", "32x24", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)[0]
    assert r["status"] == "ran" and "inputs changed" in r["reason"] and r["views"] == 3


def test_render_holdout_writes_images_and_report_contract(scene_dir, tmp_path):
    out = tmp_path / "r"
    assert render.main([str(scene_dir), "--method", "reference", "--holdout", "v001", "v004",
                        "-o", str(out), "--depth", "--float", "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["method"] == "reference" and isinstance(rep["params"], dict) and rep["threads"] >= 1
    assert [f["name"] for f in rep["frames"]] == ["v001", "v004"]
    for f in rep["frames"]:
        assert (out / f["image"]).is_file() and (out / f"{f['name']}.depth.exr").is_file()
        assert (out / f"{f['name']}.exr").is_file()
        assert f["time_ms"]["total"] > 0 and "raycast_shade" in f["time_ms"]
        m = f["metrics"]
        # The reference renderer made the held-out images: the only error is the 8-bit PNG
        # quantisation of the stored ground truth (PSNR of uniform 1/255 noise ~ 59 dB).
        assert m["psnr"] > 45 and m["ssim"] > 0.99 and m["coverage"] > 0.5
    assert "summary" in rep and rep["summary"]["frames"] == 2


def test_render_metrics_choice_and_bad_value(scene_dir, tmp_path, capsys):
    out = tmp_path / "m"
    assert render.main([str(scene_dir), "--holdout", "v001", "-o", str(out), "--metrics", "psnr", "-q"]) == 0
    m = json.loads((out / "report.json").read_text())["frames"][0]["metrics"]
    assert {"psnr", "psnr_covered", "coverage"} <= set(m) and not {"ssim", "flip"} & set(m)
    assert render.main([str(scene_dir), "--holdout", "v001", "-o", str(out), "--metrics", "none", "-q"]) == 0
    m = json.loads((out / "report.json").read_text())["frames"][0]["metrics"]
    assert "coverage" in m and not {"psnr", "ssim", "flip"} & set(m)
    capsys.readouterr()
    assert render.main([str(scene_dir), "--holdout", "v001", "-o", str(tmp_path / "bad"), "--metrics", "lpips"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--metrics: expected all, none or a comma list of psnr, ssim, flip, got 'lpips'" in err
    assert len(err.splitlines()) == 1 and not (tmp_path / "bad").exists()


def test_render_targets_path_and_poses(scene_dir, tmp_path):
    from ibrtools.formats import native
    scene = native.load(scene_dir)
    assert scene.targets and scene.paths
    assert render.main([str(scene_dir), "--target", scene.targets[0].name, "-o", str(tmp_path / "t"), "-q"]) == 0
    path = next(iter(scene.paths))
    assert render.main([str(scene_dir), "--path", path, "-o", str(tmp_path / "p"), "-q"]) == 0
    rep = json.loads((tmp_path / "p/report.json").read_text())
    assert len(rep["frames"]) == len(scene.paths[path])
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps([dict(scene.views[0].camera.to_dict(), name="mine")]))
    assert render.main([str(scene_dir), "--poses", str(poses), "-o", str(tmp_path / "q"), "-q"]) == 0
    assert (tmp_path / "q/mine.png").is_file()


def test_thread_count_does_not_change_pixels(scene_dir, tmp_path):
    from ibrtools.imageio import read_image
    for j in ("1", "2"):
        assert render.main([str(scene_dir), "--holdout", "v002", "-o", str(tmp_path / j), "-j", j, "-q"]) == 0
    assert np.array_equal(read_image(tmp_path / "1/v002.png"), read_image(tmp_path / "2/v002.png"))


@pytest.mark.parametrize("argv, msg", [
    (["{scene}", "--method", "depthwarp", "--holdout", "v001", "--layers", "0"], "--layers"),
    (["{scene}", "--holdout", "nope"], "view 'nope': not in the scene"),
    (["{scene}", "--target", "nope"], "target 'nope'"),
    (["{scene}", "--path", "nope"], "--path nope"),
    (["{scene}", "--poses", "{tmp}/absent.json"], "absent.json: no such file"),
    (["{scene}", "--poses", "{tmp}/bad.json"], "malformed JSON"),
    (["{scene}", "--holdout", "v000", "v001", "v002", "v003", "v004", "v005"], "every input view is held out"),
    (["{tmp}/absent"], "absent"),
    (["{scene}", "--holdout", "v001", "-j", "-1"], "--threads"),
    (["{scene}", "--holdout", "v001", "--param", "bogus=1"], "no parameter"),
])
def test_render_bad_input(scene_dir, tmp_path, capsys, argv, msg):
    (tmp_path / "bad.json").write_text("[{")
    args = [a.format(scene=scene_dir, tmp=tmp_path) for a in argv] + ["-o", str(tmp_path / "out")]
    assert render.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out" / "report.json").exists()


@pytest.mark.parametrize("argv, msg", [
    (["{tmp}/absent", "-o", "{tmp}/s"], "no such file or directory"),
    (["{tmp}/emptydir", "-o", "{tmp}/s"], "unknown data-set format"),
    (["synth:nope", "-o", "{tmp}/s"], "unknown preset"),
    (["synth:objects", "-o", "{tmp}/s", "--views", "0"], "--views"),
    (["{tmp}/emptydir", "-o", "{tmp}/s", "--opt", "novalue"], "key=value"),
    (["synth:objects", "-o", "{tmp}/s", "--max-size", "10"], "--max-size: for data sets only"),
    (["synth:objects", "-o", "{tmp}/s", "--set", "mesh.bogus=1"], "--set mesh.bogus: unknown parameter"),
])
def test_preprocess_bad_input(tmp_path, capsys, argv, msg):
    (tmp_path / "emptydir").mkdir()
    assert preprocess.main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1
    assert not (tmp_path / "s").exists()


def test_errors_about_arguments_read_as_flags_in_the_commands():
    """The library names the argument (its keyword); the commands print the flag that sets it."""
    args = argparse.Namespace()
    cases = [(BadValueError.about("max_size", "expected a whole number"), "max_size: expected a whole number",
              "--max-size: expected a whole number"),
             (BadValueError.about("stage_options", "unknown parameter", "mesh.bogus"),
              "stage_options 'mesh.bogus': unknown parameter", "--set mesh.bogus: unknown parameter"),
             (MissingFileError.about("method", "needs stage 'pvm'", "hybrid"), "method 'hybrid': needs stage 'pvm'",
              "--method hybrid: needs stage 'pvm'"),
             (NotBuiltError.about(("workers", "scheduler"), "needs dask"), "workers/scheduler: needs dask",
              "--workers/--scheduler: needs dask"),
             (BadValueError.about("centre", "no view", "v9"), "centre 'v9': no view", "--center v9: no view"),
             (InputError("a.png: truncated"), "a.png: truncated", "a.png: truncated"),
             (ParamError("blend_exponent", "expected >= 0"), "parameter blend_exponent: expected >= 0",
              "--param blend_exponent: expected >= 0")]
    tblib = pytest.importorskip("tblib.pickling_support")
    for e, library, command in cases:
        again = pickle.loads(pickle.dumps(e))  # raised on a Dask worker, printed by the command
        assert type(again) is type(e) and str(again) == str(e) == library
        assert error_line(again, args) == error_line(e, args) == command
    tblib.install(*{type(e) for e, _, _ in cases})  # how dask.distributed pickles a worker's errors
    for e, library, command in cases:
        again = pickle.loads(pickle.dumps(e))
        assert type(again) is type(e) and str(again) == library and error_line(again, args) == command


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as e:
        preprocess.main(["synth:objects", "-o", "x", "--size", "0x5"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        render.main(["x", "--method", "magic"])
    assert e.value.code == 2


def test_bench_bad_scene_exits_2(capsys):
    assert bench.main(["somewhere", "-o", "somewhere-out"]) == 2
    assert capsys.readouterr().err.startswith("ibr-bench: error:")


def test_installed_entry_points_exit_codes(tmp_path):
    """The console scripts themselves: --help works, bad input is one line and exit 2."""
    exe = sys.executable.rsplit("/", 1)[0]
    for cmd in ("ibr-preprocess", "ibr-render", "ibr-bench"):
        r = subprocess.run([f"{exe}/{cmd}", "--help"], capture_output=True, text=True)
        assert r.returncode == 0 and "usage" in r.stdout
    r = subprocess.run([f"{exe}/ibr-render", str(tmp_path / "nothing")], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "nothing" in r.stderr


# --- progress, --json, summary totals --------------------------------------------------
def test_render_json_is_the_report_and_nothing_else(scene_dir, tmp_path, capsys):
    out = tmp_path / "j"
    assert render.main([str(scene_dir), "--method", "reference", "--holdout", "v001", "v002", "-o", str(out),
                        "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out) == json.loads((out / "report.json").read_text())
    assert cap.err == ""  # not a terminal: no bar


def test_render_summary_table_has_totals(scene_dir, tmp_path, capsys):
    assert render.main([str(scene_dir), "--method", "reference", "--holdout", "v001", "v002",
                        "-o", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    rep = json.loads((tmp_path / "t/report.json").read_text())
    assert "2 frames" in out and f"median {rep['summary']['time_ms']['median']:.1f}" in out
    assert f"{rep['summary']['mean_psnr']:.2f}" in out


class _FakeTerminal:
    def __init__(self):
        import io
        self.buf = io.StringIO()

    def isatty(self):
        return True

    def write(self, s):
        return self.buf.write(s)

    def flush(self):
        pass


def test_progress_bar_helper():
    from ibrtools_cli.common import progress_bar

    term = _FakeTerminal()
    with progress_bar("ibr-x", "frames", 3, stream=term) as bar:
        assert bar.shown
        for i in range(3):
            bar.update(i, 3, f"f{i}")
        bar.update(3, 3, "")
    text = term.buf.getvalue()
    assert "ibr-x" in text and "3/3" in text
    term = _FakeTerminal()
    with progress_bar("ibr-x", "frames", 3, stream=term, quiet=True) as bar:
        assert not bar.shown
        bar.update(1, 3, "x")
        bar.advance("y")
    assert term.buf.getvalue() == ""
    import io
    with progress_bar("ibr-x", "frames", 3, stream=io.StringIO()) as bar:  # not a terminal: no bar
        assert not bar.shown


def _run_with_terminal_stderr(argv: list[str], timeout: float = 300) -> tuple[int, str, str]:
    """Run a command with stderr on a pseudo-terminal (so the bar shows) and stdout on a pipe."""
    import os
    import pty
    import select

    master, slave = pty.openpty()
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=slave, stdin=subprocess.DEVNULL)
    os.close(slave)
    err = b""
    try:
        while True:
            ready, _, _ = select.select([master], [], [], 0.1)
            if ready:
                try:
                    chunk = os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    chunk = b""
                if not chunk:
                    break
                err += chunk
            elif p.poll() is not None:
                break
        out = p.stdout.read()
        p.wait(timeout)
    finally:
        os.close(master)
    return p.returncode, out.decode(), err.decode(errors="replace")


def test_progress_bars_on_a_terminal_and_json_alone_on_stdout(scene_dir, tmp_path):
    exe = sys.executable.rsplit("/", 1)[0]
    rc, out, err = _run_with_terminal_stderr([f"{exe}/ibr-render", str(scene_dir), "--method", "reference",
                                              "--holdout", "v001", "v002", "-o", str(tmp_path / "r"), "--json"])
    assert rc == 0 and json.loads(out)["summary"]["frames"] == 2
    assert "ibr-render" in err and "frames" in err and "2/2" in err
    # ibr-preprocess: the stage bar on the terminal, the table on stdout (--quiet and --json turn
    # the bar off in the same helper: test_progress_bar_helper).
    rc, out, err = _run_with_terminal_stderr([f"{exe}/ibr-preprocess", "synth:objects", "-o", str(tmp_path / "s"),
                                              "--views", "2", "--size", "32x24"])
    assert rc == 0 and "stages" in err and "done" in err and "import" in out
