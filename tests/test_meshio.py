"""Mesh I/O (ibrtools.meshio): PLY and OBJ + texture round trips, sidecar, real meshes.

Tolerances: binary PLY stores float vertices exactly; open3d writes OBJ numbers with 6
significant digits (relative 1e-6, so 1e-5 absolute for unit-scale meshes). Colours go
through 8-bit sRGB: half a step (0.5 / 255) in sRGB is at most 0.0045 in linear, so 0.005.
"""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import Camera, DtypeError, FormatError, Mesh, MissingFileError, look_at
from ibrtools.meshio import read_mesh, sidecar_path, write_mesh
from ibrtools.raycast.reference import ReferenceRenderer

COLOR_TOL = 0.005
OBJ_TOL = 1e-5


def _mesh(rng, textured=False):
    v = rng.random((8, 3)).astype(np.float32)
    f = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6], [5, 6, 7], [1, 2, 7], [0, 3, 6]], np.int32)
    kw = {}
    if textured:
        kw = dict(uvs=rng.random((6, 3, 2)), textures=[rng.random((4, 6, 3)), rng.random((8, 4, 3))],
                  texture_ids=np.array([1, 0, 1, -1, 1, 0], np.int32))
    else:
        kw = dict(vertex_colors=rng.random((8, 3)))
    return Mesh(v, f, object_ids=np.array([0, 1, 2, 3, 4, 2], np.int32),
                materials=rng.random((5, 2)).astype(np.float32), **kw)


def test_ply_round_trip_with_sidecar(tmp_path, rng):
    m = _mesh(rng)
    out = write_mesh(tmp_path / "m.ply", m)
    assert out == tmp_path / "m.ply" and sidecar_path(out).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.ply", "m.ply.attrs.npz"]  # no temp left
    r = read_mesh(out, kind="reconstructed")
    assert r.kind == "reconstructed"
    np.testing.assert_array_equal(r.vertices, m.vertices)
    np.testing.assert_array_equal(r.faces, m.faces)
    np.testing.assert_allclose(r.vertex_colors, m.vertex_colors, atol=COLOR_TOL)
    np.testing.assert_array_equal(r.object_ids, m.object_ids)
    np.testing.assert_array_equal(r.materials, m.materials)


def test_obj_round_trip_with_textures(tmp_path, rng):
    m = _mesh(rng, textured=True)
    write_mesh(tmp_path / "t.obj", m)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert "t.obj" in names and "t.mtl" in names and "t.obj.attrs.npz" in names
    assert not [n for n in names if n.startswith(".")]
    r = read_mesh(tmp_path / "t.obj")
    # faces come back sorted by texture (stable); the untextured face uses an extra grey texture
    tids = np.where(m.texture_ids < 0, 2, m.texture_ids)
    order = np.argsort(tids, kind="stable")
    np.testing.assert_allclose(r.vertices[r.faces], m.vertices[m.faces][order], atol=OBJ_TOL)
    np.testing.assert_allclose(r.uvs, m.uvs[order], atol=OBJ_TOL)
    np.testing.assert_array_equal(r.object_ids, m.object_ids[order])
    assert len(r.textures) == 3
    for k in range(2):
        np.testing.assert_allclose(r.textures[r.texture_ids[tids[order] == k][0]], m.textures[k], atol=COLOR_TOL)
    np.testing.assert_allclose(r.textures[r.texture_ids[tids[order] == 2][0]], 0.8, atol=COLOR_TOL)


def test_obj_round_trip_renders_the_same(tmp_path, rng):
    # A textured quad: the written and re-read mesh shade like the original.
    v = np.array([[-1, 1, 4], [1, 1, 4], [1, -1, 4], [-1, -1, 4]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    uvs = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    m = Mesh(v, f, uvs=uvs, textures=[rng.random((16, 16, 3)).astype(np.float32)])
    write_mesh(tmp_path / "q.obj", m)
    assert not sidecar_path(tmp_path / "q.obj").exists()  # one object, no materials: no sidecar
    cam = Camera.from_fov(32, 32, 40)
    a = ReferenceRenderer(m).render(cam, outputs=("color",), lights=[], ambient=1.0)["color"]
    b = ReferenceRenderer(read_mesh(tmp_path / "q.obj")).render(cam, outputs=("color",), lights=[],
                                                                 ambient=1.0)["color"]
    np.testing.assert_allclose(a, b, atol=COLOR_TOL)


def test_stale_sidecar_removed(tmp_path, rng):
    write_mesh(tmp_path / "m.ply", _mesh(rng))
    m = Mesh(np.eye(3, dtype=np.float32), np.array([[0, 1, 2]], np.int32))
    write_mesh(tmp_path / "m.ply", m)
    assert not sidecar_path(tmp_path / "m.ply").exists()
    assert np.all(read_mesh(tmp_path / "m.ply").object_ids == 0)


def test_bad_input(tmp_path, rng):
    with pytest.raises(MissingFileError, match="no such mesh file"):
        read_mesh(tmp_path / "nope.ply")
    (tmp_path / "m.xyz").write_text("1 2 3\n")
    with pytest.raises(FormatError, match="unknown mesh extension"):
        read_mesh(tmp_path / "m.xyz")
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(FormatError, match="no triangles"):
        read_mesh(tmp_path / "empty.ply")
    (tmp_path / "junk.obj").write_text("this is not an obj file\n")
    with pytest.raises(FormatError, match="no triangles"):
        read_mesh(tmp_path / "junk.obj")
    (tmp_path / "pts.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")  # vertices, no faces
    with pytest.raises(FormatError):
        read_mesh(tmp_path / "pts.obj")
    with pytest.raises(FormatError, match="PLY cannot hold textures"):
        write_mesh(tmp_path / "t.ply", _mesh(rng, textured=True))
    assert not (tmp_path / "t.ply").exists()
    with pytest.raises(FormatError, match="unknown mesh extension"):
        write_mesh(tmp_path / "t.stl", _mesh(rng))
    with pytest.raises(DtypeError, match="ibrtools.Mesh"):
        write_mesh(tmp_path / "t.ply", (np.eye(3), [[0, 1, 2]]))
    # a sidecar that does not belong to the mesh, and one that is not an npz
    write_mesh(tmp_path / "m.ply", _mesh(rng))
    np.savez(sidecar_path(tmp_path / "m.ply"), num_faces=3, object_ids=np.zeros(3, np.int32))
    with pytest.raises(FormatError, match="sidecar is for a mesh of 3 faces"):
        read_mesh(tmp_path / "m.ply")
    sidecar_path(tmp_path / "m.ply").write_bytes(b"garbage")
    with pytest.raises(FormatError, match="unreadable mesh sidecar"):
        read_mesh(tmp_path / "m.ply")
    with pytest.raises(MissingFileError):
        read_mesh(tmp_path / "m.ply", texture=tmp_path / "missing.png")


# --- real meshes (../shared/data/meshes) ---------------------------------------------------------
def test_spot_uv_convention(data_dir):
    """The OBJ convention, pinned on a real textured mesh: the faces whose uvs fall on the eyes
    of spot's texture (texel rows 700-750 from the top, i.e. v = 1 - row / 1024) sit above
    the faces that fall on its nose (rows 760-880), both on the front of the head. With v
    read the other way up these uv boxes land on the body instead."""
    d = data_dir / "meshes" / "spot"
    m = read_mesh(d / "spot_triangulated.obj", texture=d / "spot_texture.png")
    assert len(m.faces) == 5856 and m.uvs.shape == (5856, 3, 2) and m.textures[0].shape == (1024, 1024, 3)
    uvc, pc = m.uvs.mean(1), m.vertices[m.faces].mean(1)

    def box(c0, c1, r0, r1):
        row = (1 - uvc[:, 1]) * 1024
        return (uvc[:, 0] * 1024 >= c0) & (uvc[:, 0] * 1024 <= c1) & (row >= r0) & (row <= r1)

    eyes, nose = pc[box(230, 315, 700, 750)], pc[box(180, 370, 760, 880)]
    assert len(eyes) > 10 and len(nose) > 50
    assert eyes[:, 1].mean() > nose[:, 1].mean() + 0.2      # eyes above the nose (+y up)
    assert abs(eyes[:, 2].mean() - nose[:, 2].mean()) < 0.1  # both on the face ...
    assert eyes[:, 2].mean() < 0.6 * m.vertices[:, 2].min()  # ... at the front (-z) of the cow
    # and the renderer shows the eyes' black texels on the head seen from the front
    cam = Camera.from_fov(96, 96, 40, look_at([0, 0.5, -2.5], [0, 0.45, -0.5]))
    c = ReferenceRenderer(m).render(cam, outputs=("color",), lights=[], ambient=1.0)["color"]
    assert (c.max(-1) < 0.05).sum() > 5


def test_crate_quads_and_texture(data_dir):
    m = read_mesh(data_dir / "meshes" / "crate" / "crate.obj")
    assert m.faces.shape == (12, 3)  # 6 quads, triangulated
    assert len(m.textures) == 1 and m.textures[0].shape == (320, 320, 3)
    assert m.textures[0].dtype == np.float32 and 0 <= m.textures[0].min() and m.textures[0].max() <= 1
    assert m.uvs.min() >= 0 and m.uvs.max() <= 1
    np.testing.assert_allclose(np.abs(m.vertices), 1.0)
