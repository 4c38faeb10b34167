"""Native scene format: exact round trip, lazy loading, atomic save, clear errors."""
import json

import numpy as np
import pytest

from ibrtools import BadValueError, Camera, FormatError, MissingFileError, Scene, ShapeError, View, look_at
from ibrtools.formats import detect, load, native


def small_scene(rng) -> Scene:
    views = []
    for i in range(3):
        cam = Camera.pinhole(16, 12, 14.0 + i, 14.5, 8.1, 5.9, look_at([np.cos(i), 0.3, np.sin(i) + 3], [0, 0, 0]))
        depth = rng.uniform(1, 4, (12, 16)).astype(np.float32)
        depth[0, 0] = 0.0  # unknown
        views.append(View.create(f"v{i:03d}", cam, color=rng.uniform(0, 1, (12, 16, 3)).astype(np.float32),
                                 depth=depth, mask=rng.uniform(size=(12, 16)) > 0.5))
    target = View.create("t0", Camera.equirect(32, 16, (-170, 170), (-60, 80), look_at([0, 0, 4], [0, 0, 0])))
    return Scene(views=views, targets=[target], paths={"p": [views[0].camera, views[1].camera]},
                 units="m", source={"format": "test", "far": float("inf")})


def test_round_trip_exact_cameras_and_lossless_depth(tmp_path, rng):
    s = small_scene(rng)
    native.save(s, tmp_path / "scene")
    assert detect(tmp_path / "scene") == "native"
    t = load(tmp_path / "scene")
    assert [v.name for v in t.views] == ["v000", "v001", "v002"] and t.targets[0].name == "t0"
    for a, b in zip(s.views + s.targets, t.views + t.targets):
        assert b.camera.allclose(a.camera, 1e-12)
    for a, b in zip(s.views, t.views):
        assert np.array_equal(a.depth, b.depth)            # EXR float32: lossless
        assert np.array_equal(a.mask, b.mask)
        assert np.abs(a.color - b.color).max() < 1.3e-2    # 8-bit sRGB: under one code step
    assert t.paths["p"][1].allclose(s.paths["p"][1], 1e-12)
    assert t.units == "m" and t.source["far"] == "inf"
    assert not t.targets[0].has_color


def test_exr_colour_is_lossless(tmp_path, rng):
    s = small_scene(rng)
    native.save(s, tmp_path / "scene", color_format="exr")
    t = load(tmp_path / "scene")
    assert np.array_equal(s.views[1].color, t.views[1].color)


def test_images_load_lazily_and_report_their_file(tmp_path, rng):
    native.save(small_scene(rng), tmp_path / "s")
    f = tmp_path / "s/images/v001.depth.exr"
    f.write_bytes(f.read_bytes()[:-64])  # the header is intact, the pixels are cut short
    t = load(tmp_path / "s")          # loading the scene reads headers, not pixels
    assert t.views[0].depth is not None
    with pytest.raises(FormatError, match="v001.depth.exr"):
        _ = t.views[1].depth
    f.write_bytes(b"garbage")         # an unreadable header is found when the scene is loaded
    with pytest.raises(FormatError, match="v001.depth.exr: not a readable image"):
        load(tmp_path / "s")


def test_meshes_load_lazily_and_report_their_file(tmp_path, rng):
    # A mesh is read when first asked for (a video's frames rendered by DIBR never read theirs);
    # a missing file is still found when the scene is loaded, a corrupt one names itself on use.
    import pickle

    from ibrtools.mesh import Mesh
    from ibrtools.scene import LazyMeshes

    s = small_scene(rng)
    s.meshes["ground_truth"] = Mesh(vertices=np.array([[0, 0, 3], [1, 0, 3], [0, 1, 3]], np.float32),
                                    faces=np.array([[0, 1, 2]], np.int32))
    native.save(s, tmp_path / "s")
    t = load(tmp_path / "s")
    assert isinstance(t.meshes, LazyMeshes) and "not read yet" in repr(t.meshes)
    assert list(t.meshes) == ["ground_truth"] and len(t.meshes) == 1 and "reconstructed" not in t.meshes
    again = pickle.loads(pickle.dumps(t)).meshes  # Dask workers get scenes pickled, unread meshes too
    m = t.meshes["ground_truth"]
    assert t.meshes["ground_truth"] is m and "read" in repr(t.meshes) and np.array_equal(m.faces, [[0, 1, 2]])
    assert np.array_equal(again["ground_truth"].vertices, m.vertices)
    assert dict(t.meshes) == {"ground_truth": m} and t.meshes.get("reconstructed") is None
    f = tmp_path / "s" / json.loads((tmp_path / "s/scene.json").read_text())["meshes"]["ground_truth"]["path"]
    f.write_bytes(b"garbage")
    t = load(tmp_path / "s")           # the file's existence is checked at load, its content on use
    with pytest.raises(FormatError, match=f.name):
        _ = t.meshes["ground_truth"]
    f.unlink()
    with pytest.raises(MissingFileError, match=f.name):
        load(tmp_path / "s")


def test_save_replaces_atomically_and_refuses_foreign_dirs(tmp_path, rng):
    s = small_scene(rng)
    native.save(s, tmp_path / "s")
    native.save(s, tmp_path / "s")  # replacing a scene is fine
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "precious.txt").write_text("x")
    with pytest.raises(BadValueError, match="not a scene directory"):
        native.save(s, tmp_path / "other")
    assert (tmp_path / "other" / "precious.txt").exists()


def test_failed_save_leaves_nothing(tmp_path, rng, monkeypatch):
    import ibrtools.formats.native as nat

    s = small_scene(rng)

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(nat, "write_depth", boom)
    with pytest.raises(RuntimeError):
        native.save(s, tmp_path / "s")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("mutate, err, msg", [
    (lambda d: d.update(version=99), FormatError, "version 99"),
    (lambda d: d.update(format="x"), FormatError, "not an ibrtools scene"),
    (lambda d: d["views"][0]["camera"].update(fx=0.0), BadValueError, r"views\[0\].camera: fx"),
    (lambda d: d["views"][0]["camera"].update(cam_from_world=np.diag([2.0, 1, 1, 1]).tolist()),
     BadValueError, "not a rigid pose"),
    (lambda d: d["views"][0].update(color="images/missing.png"), MissingFileError, "missing.png"),
    (lambda d: d["views"][1].update(name="v000"), BadValueError, "duplicate"),
    (lambda d: d.update(views=[], targets=[]), BadValueError, "empty"),
])
def test_bad_scene_json(tmp_path, rng, mutate, err, msg):
    native.save(small_scene(rng), tmp_path / "s")
    f = tmp_path / "s" / "scene.json"
    doc = json.loads(f.read_text())
    mutate(doc)
    f.write_text(json.dumps(doc))
    with pytest.raises(err, match=msg):
        load(tmp_path / "s")


def test_mismatched_image_and_depth_sizes(tmp_path, rng):
    from ibrtools.imageio import write_depth
    native.save(small_scene(rng), tmp_path / "s")
    write_depth(tmp_path / "s/images/v000.depth.exr", np.ones((5, 5), np.float32))
    with pytest.raises(ShapeError, match=r"v000.depth.exr: image is 5x5, the camera says 16x12"):
        load(tmp_path / "s")


def test_not_json(tmp_path):
    (tmp_path / "scene.json").write_text("{nope")
    with pytest.raises(FormatError, match="malformed JSON"):
        native.load(tmp_path)
    with pytest.raises(MissingFileError):
        load(tmp_path / "absent")
