"""Fuzzing the importers: hypothesis-generated malformed inputs.

Each entry point starts from a small valid fixture (the ones the importer tests write) and
gets mutated bytes (truncation, overwritten / inserted / deleted bytes) or a mutated JSON
document (a subtree replaced by an arbitrary JSON value, a key deleted, the text cut short).
The contract checked for every case: the call either succeeds and everything it returns is
sane (finite colour, valid depth, the scene validates, lazy images load), or it raises an
``InputError`` subclass with a non-empty message. Any other exception is a crash; a call
running past ``HANG_S`` seconds is a hang. Examples are bounded and derandomised so the
suite stays fast and reproducible; ``IBR_FUZZ_EXAMPLES`` scales them up for a long run, and
``IBR_FUZZ_COUNTS=path.json`` writes the number of cases run per entry point
(docs/robustness.md quotes these counts).
"""
from __future__ import annotations

import collections
import json
import os
import shutil
import signal
import struct
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ibrtools.errors import InputError
from ibrtools.formats import colmap, load, mpeg, native, nerf, rgbd, yuv
from ibrtools.imageio import read_depth, read_image, read_mask, write_depth, write_image

pytestmark = [pytest.mark.asan]

EXAMPLES = int(os.environ.get("IBR_FUZZ_EXAMPLES", "40"))
HANG_S = 20  # a 16x12 fixture loads in milliseconds; 20 s leaves room for a loaded CI machine
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large, HealthCheck.filter_too_much])
COUNTS: collections.Counter = collections.Counter()
OUTCOMES: collections.Counter = collections.Counter()


@pytest.fixture(scope="module", autouse=True)
def _write_counts():
    yield
    out = os.environ.get("IBR_FUZZ_COUNTS")
    if out:
        p = Path(out)
        old = json.loads(p.read_text()) if p.is_file() else {}
        for k, v in COUNTS.items():
            old[k] = {"cases": old.get(k, {}).get("cases", 0) + v,
                      "rejected": old.get(k, {}).get("rejected", 0) + OUTCOMES[k + ":rejected"],
                      "accepted": old.get(k, {}).get("accepted", 0) + OUTCOMES[k + ":accepted"]}
        p.write_text(json.dumps(old, indent=1, sort_keys=True))


@contextmanager
def _deadline(what: str):
    """Fail (instead of hanging the suite) when one case runs past HANG_S seconds."""
    def on_alarm(signum, frame):
        raise AssertionError(f"{what}: no answer after {HANG_S} s (hang)")
    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(HANG_S)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def expect_typed(entry: str, fn, *args, **kw):
    """Run one case: returns the result, or None when it was rejected with a typed error."""
    COUNTS[entry] += 1
    with _deadline(entry):
        try:
            out = fn(*args, **kw)
        except InputError as e:
            assert str(e).strip(), f"{entry}: {type(e).__name__} with an empty message"
            OUTCOMES[entry + ":rejected"] += 1
            return None
    OUTCOMES[entry + ":accepted"] += 1
    return out


def check_scene(entry: str, scene) -> None:
    """An accepted scene must be usable: every lazy image loads (or is rejected typed) and is sane."""
    def touch():
        for v in list(scene.views) + list(scene.targets):
            c = v.color
            if c is not None:
                assert c.dtype == np.float32 and np.all(np.isfinite(c)), f"{entry}: {v.name}: bad colour"
            d = v.depth
            if d is not None:
                assert d.dtype == np.float32 and not np.any(np.isnan(d)), f"{entry}: {v.name}: NaN depth"
                assert not np.any(d < 0), f"{entry}: {v.name}: negative depth"
            v.mask  # noqa: B018 - the loader runs on access
        return True
    expect_typed(entry + " (lazy images)", touch)


# --- mutation strategies --------------------------------------------------------------------------
@st.composite
def byte_mutations(draw, data: bytes) -> bytes:
    """A few random edits of ``data``: truncate, overwrite, insert, delete, or swap a number."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["truncate", "overwrite", "insert", "delete", "int32"]))
        n = len(out)
        pos = draw(st.integers(0, max(n - 1, 0)))
        if op == "truncate":
            del out[pos:]
        elif op == "overwrite" and n:
            chunk = draw(st.binary(min_size=1, max_size=8))
            out[pos:pos + len(chunk)] = chunk
        elif op == "insert":
            out[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif op == "delete":
            del out[pos:pos + draw(st.integers(1, 16))]
        elif op == "int32" and n >= pos + 4:
            # header fields are where size mistakes hide: plant an extreme integer
            v = draw(st.sampled_from([0, 1, -1, 2**31 - 1, -2**31, 2**16, 3, 7]))
            out[pos:pos + 4] = struct.pack("<i", v)
    return bytes(out)


JSON_LEAF = (st.none() | st.booleans() | st.integers(-2**63, 2**63) |
             st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=12) |
             st.sampled_from([0, -1, 1e308, -1e-308, 5e-324, "", "../../etc/passwd", "a\0b"]))
JSON_VALUE = st.recursive(JSON_LEAF, lambda kids: st.lists(kids, max_size=4) |
                          st.dictionaries(st.text(max_size=8), kids, max_size=4), max_leaves=8)


@st.composite
def json_mutations(draw, doc) -> str:
    """``doc`` with one subtree replaced or deleted, serialised; sometimes cut short."""
    doc = json.loads(json.dumps(doc))
    parent, key, node = None, None, doc
    while isinstance(node, (dict, list)) and node and draw(st.integers(0, 3)) > 0:
        keys = list(node.keys()) if isinstance(node, dict) else list(range(len(node)))
        parent, key = node, draw(st.sampled_from(keys))
        node = node[key]
    if parent is None:
        doc = draw(JSON_VALUE) if draw(st.booleans()) else doc
    elif draw(st.integers(0, 3)) == 0:
        del parent[key]
    else:
        parent[key] = draw(JSON_VALUE)
    text = json.dumps(doc)
    if draw(st.integers(0, 5)) == 0:
        text = text[:draw(st.integers(0, max(len(text) - 1, 0)))]
    return text


def fresh_copy(seed: Path) -> Path:
    d = Path(tempfile.mkdtemp(prefix="ibrfuzz-"))
    dst = d / "data"
    shutil.copytree(seed, dst)
    return dst


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    """Valid fixtures, written once per module by the importer tests' own writers."""
    import test_import_colmap as tc
    import test_import_mpeg as tm
    import test_import_nerf as tn
    import test_import_rgbd as tr
    from test_native import small_scene

    base = tmp_path_factory.mktemp("seeds")
    s = {}
    s["colmap_bin"] = tc.make(base / "colmap_bin", kind="bin")
    s["colmap_txt"] = tc.make(base / "colmap_txt", kind="txt")
    (base / "mpeg").mkdir()
    s["mpeg_cams"] = tm.make_content(base / "mpeg")
    (base / "nerf").mkdir()
    s["nerf"] = tn.make_set(base / "nerf")
    (base / "rgbd").mkdir()
    s["rgbd"] = tr.make(base / "rgbd")
    scene = small_scene(np.random.default_rng(5))
    native.save(scene, base / "native")
    s["native"] = base / "native"
    img = np.random.default_rng(1).uniform(0, 1, (6, 5, 3)).astype(np.float32)
    for ext in ("png", "exr"):
        write_image(base / f"img.{ext}", img)
        s[f"img_{ext}"] = base / f"img.{ext}"
    write_depth(base / "depth.exr", np.full((6, 5), 2.0, np.float32))
    s["depth_exr"] = base / "depth.exr"
    # a hand-written PFM (no writer needed): 'Pf' grey, 5x6, little-endian scale -1
    (base / "depth.pfm").write_bytes(b"Pf\n5 6\n-1.0\n" + np.full(30, 2.0, "<f4").tobytes())
    s["depth_pfm"] = base / "depth.pfm"
    arr = np.arange(6 * 5, dtype=np.float32).reshape(6, 5) + 1
    (base / "arr.bin").write_bytes(b"5&6&1&" + arr.tobytes())
    s["colmap_array"] = base / "arr.bin"
    s["ply_ascii"] = base / "tri.ply"
    s["ply_ascii"].write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                              "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                              "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    s["ply_bin"] = base / "trib.ply"
    s["ply_bin"].write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                             b"property float y\nproperty float z\nelement face 1\n"
                             b"property list uchar int vertex_indices\nend_header\n"
                             + np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes()
                             + b"\x03" + np.array([0, 1, 2], "<i4").tobytes())
    return s


# --- image headers: PNG / EXR / PFM ----------------------------------------------------------------
@pytest.mark.parametrize("which", ["img_png", "img_exr", "depth_pfm", "depth_exr"])
@FUZZ
@given(data=st.data())
def test_image_files(seeds, which, data):
    src = seeds[which]
    blob = data.draw(byte_mutations(src.read_bytes()))
    d = Path(tempfile.mkdtemp(prefix="ibrfuzz-"))
    try:
        p = d / src.name
        p.write_bytes(blob)
        if which.startswith("img"):
            out = expect_typed(f"read_image({src.suffix})", read_image, p)
            if out is not None:
                assert out.ndim == 3 and out.shape[2] == 3 and np.all(np.isfinite(out))
            m = expect_typed(f"read_mask({src.suffix})", read_mask, p)
            if m is not None:
                assert m.dtype == bool and m.ndim == 2
        else:
            out = expect_typed(f"read_depth({src.suffix})", read_depth, p)
            if out is not None:
                assert out.dtype == np.float32 and out.ndim == 2
    finally:
        shutil.rmtree(d, ignore_errors=True)


# --- raw YUV: wrong sizes, bit depths, frames ------------------------------------------------------
@FUZZ
@given(size=st.integers(0, 600), width=st.integers(-3, 40), height=st.integers(-3, 40),
       bits=st.integers(-1, 20), frame=st.integers(-2, 4), chroma=st.sampled_from(["420", "400", "444", ""]))
def test_yuv_read_frame(tmp_path, size, width, height, bits, frame, chroma):
    p = tmp_path / "f.yuv"
    p.write_bytes(bytes(range(256)) * (size // 256) + bytes(size % 256))
    planes = expect_typed("yuv.read_frame", yuv.read_frame, p, width, height, bits, frame, chroma)
    if planes is not None:
        shapes = yuv.plane_shapes(width, height, chroma)
        assert [pl.shape for pl in planes] == shapes
        rgb = expect_typed("yuv.yuv_to_rgb", yuv.yuv_to_rgb, planes, bits)
        if rgb is not None and chroma == "420":
            assert rgb.shape == (height, width, 3) and np.all(np.isfinite(rgb))


# --- COLMAP: binary and text models, dense arrays ---------------------------------------------------
@pytest.mark.parametrize("kind", ["bin", "txt"])
@pytest.mark.parametrize("stem", ["cameras", "images"])
@FUZZ
@given(data=st.data())
def test_colmap_model(seeds, kind, stem, data):
    root = fresh_copy(seeds[f"colmap_{kind}"])
    try:
        f = root / "sparse" / "0" / f"{stem}.{kind}"
        f.write_bytes(data.draw(byte_mutations(f.read_bytes())))
        reader = colmap.read_cameras if stem == "cameras" else colmap.read_images
        expect_typed(f"colmap.read_{stem}(.{kind})", reader, f)
        scene = expect_typed(f"colmap.load(.{kind})", load, root, "colmap")
        if scene is not None:
            check_scene(f"colmap.load(.{kind})", scene)
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)


@FUZZ
@given(data=st.data())
def test_colmap_array(seeds, data):
    src = seeds["colmap_array"]
    d = Path(tempfile.mkdtemp(prefix="ibrfuzz-"))
    try:
        p = d / "a.bin"
        p.write_bytes(data.draw(byte_mutations(src.read_bytes())))
        arr = expect_typed("colmap.read_array", colmap.read_array, p)
        if arr is not None:
            assert arr.dtype == np.float32 and arr.ndim in (2, 3) and arr.size > 0
    finally:
        shutil.rmtree(d, ignore_errors=True)


# --- JSON importers: native scene.json, MPEG camera file, NeRF transforms ---------------------------
def _json_case(entry: str, root: Path, rel: str, fmt: str, data) -> None:
    f = root / rel
    f.write_text(data.draw(json_mutations(json.loads(f.read_text()))))
    scene = expect_typed(entry, load, root if fmt != "mpeg" else f, fmt)
    if scene is not None:
        check_scene(entry, scene)


@FUZZ
@given(data=st.data())
def test_native_scene_json(seeds, data):
    root = fresh_copy(seeds["native"])
    try:
        _json_case("native.load(scene.json)", root, "scene.json", "native", data)
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)


@FUZZ
@given(data=st.data())
def test_mpeg_camera_json(seeds, data):
    root = fresh_copy(seeds["mpeg_cams"].parent)
    try:
        _json_case("mpeg.load(cameras json)", root, seeds["mpeg_cams"].name, "mpeg", data)
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)


@FUZZ
@given(data=st.data())
def test_mpeg_yuv_bytes(seeds, data):
    root = fresh_copy(seeds["mpeg_cams"].parent)
    try:
        f = sorted(root.glob("*.yuv"))[data.draw(st.integers(0, 3))]
        f.write_bytes(data.draw(byte_mutations(f.read_bytes())))
        scene = expect_typed("mpeg.load(yuv bytes)", load, root / seeds["mpeg_cams"].name, "mpeg")
        if scene is not None:
            check_scene("mpeg.load(yuv bytes)", scene)
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)


@FUZZ
@given(data=st.data())
def test_nerf_transforms_json(seeds, data):
    root = fresh_copy(seeds["nerf"])
    try:
        _json_case("nerf.load(transforms json)", root, "transforms_test.json", "nerf", data)
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)


# --- RGB-D pose lists ----------------------------------------------------------------------------
@FUZZ
@given(data=st.data())
def test_rgbd_pose_text(seeds, data):
    root = fresh_copy(seeds["rgbd"])
    try:
        f = root / "pose.txt"
        f.write_bytes(data.draw(byte_mutations(f.read_bytes())))
        scene = expect_typed("rgbd.load(pose.txt)", load, root, "rgbd")
        if scene is not None:
            check_scene("rgbd.load(pose.txt)", scene)
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)


# --- PLY meshes (ASCII and binary headers) ----------------------------------------------------------
@pytest.mark.parametrize("which", ["ply_ascii", "ply_bin"])
@FUZZ
@given(data=st.data())
def test_ply(seeds, which, data):
    from ibrtools.meshio import read_mesh

    src = seeds[which]
    d = Path(tempfile.mkdtemp(prefix="ibrfuzz-"))
    try:
        p = d / "m.ply"
        p.write_bytes(data.draw(byte_mutations(src.read_bytes())))
        mesh = expect_typed(f"read_mesh({which})", read_mesh, p)
        if mesh is not None:
            assert np.all(np.isfinite(mesh.vertices))
            assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def test_seeds_are_valid(seeds):
    """The unmutated fixtures load (otherwise every case would only test the first rejection)."""
    for k in ("colmap_bin", "colmap_txt", "native", "nerf", "rgbd"):
        check_scene(k, load(seeds[k], None if k.startswith("colmap") else k))
    check_scene("mpeg", load(seeds["mpeg_cams"], "mpeg"))
    assert colmap.read_array(seeds["colmap_array"]).shape == (6, 5)
    assert read_depth(seeds["depth_pfm"]).shape == (6, 5)


# --- the failures fuzzing found, pinned as plain regression tests -----------------------------------
def test_found_exr_error_text_not_utf8(seeds, tmp_path):
    """A corrupt EXR header put raw bytes into OpenImageIO's error text: UnicodeDecodeError before."""
    blob = bytearray(seeds["img_exr"].read_bytes())
    # the first attribute name runs on into a 0x80 byte: OpenImageIO's error text quotes it
    blob[blob.index(b"capDate\0") + 7] = 0x80
    p = tmp_path / "bad.exr"
    p.write_bytes(bytes(blob))
    with pytest.raises(InputError):
        read_image(p)


@pytest.mark.parametrize("body,msg", [
    # no 'y' property: open3d's reader crashed the process (segmentation fault)
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float z\nelement face 1\n"
     b"property list uchar int vertex_indices\nend_header\n0 0\n1 0\n0 1\n3 0 1 2\n", "x, y and z"),
    # a vertex line short of one value shifts the token stream: a 0-corner face crashed open3d
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
     b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n10 0\n0 1 0\n3 0 1 2\n",
     "faces announced"),
    # 3000 faces announced, one present: accepted silently before
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
     b"property float z\nelement face 3000\nproperty list uchar int vertex_indices\nend_header\n"
     + np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() + b"\x03" + np.array([0, 1, 2], "<i4").tobytes(),
     "faces announced"),
])
def test_found_ply_crashes(tmp_path, body, msg):
    from ibrtools.errors import FormatError
    from ibrtools.meshio import read_mesh

    p = tmp_path / "m.ply"
    p.write_bytes(body)
    with pytest.raises(FormatError, match=msg):
        read_mesh(p)


def test_found_yuv_zero_size(tmp_path):
    """Width or height 0: ZeroDivisionError before."""
    from ibrtools.errors import BadValueError

    p = tmp_path / "f.yuv"
    p.write_bytes(b"\0")
    with pytest.raises(BadValueError, match="positive integers"):
        yuv.read_frame(p, 0, 0, 8)


def test_found_json_wrong_types(seeds, tmp_path):
    """A string where a range is expected (TypeError before), null bit depth (TypeError before)."""
    from ibrtools.errors import FormatError

    root = fresh_copy(seeds["native"])
    doc = json.loads((root / "scene.json").read_text())
    doc["targets"][0]["camera"]["lon_range_deg"] = "0"
    (root / "scene.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="malformed camera"):
        load(root, "native")
    doc["targets"] = None
    (root / "scene.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="malformed content"):
        load(root, "native")
    shutil.rmtree(root.parent, ignore_errors=True)
    cams = json.loads(seeds["mpeg_cams"].read_text())
    cams["cameras"][0]["BitDepthDepth"] = None
    (tmp_path / "cams.json").write_text(json.dumps(cams))
    with pytest.raises(FormatError, match="malformed content"):
        mpeg.read_camera_file(tmp_path / "cams.json")
