"""Mesh I/O through open3d: PLY (vertex colours) and OBJ + MTL (textures).

Conventions (checked against real files: ``spot`` and ``crate`` in ../shared/data/meshes):

* **UVs** are kept exactly as the OBJ file stores them (open3d does not flip them), i.e. the
  OBJ convention of :class:`ibrtools.Mesh`: the origin is the *bottom-left* of the texture, so
  texel row = (1 - v) * H and column = u * W. Textures are arrays with row 0 at the *top* of
  the image file (as OpenImageIO and open3d both read them). tests/test_meshio.py pins this on
  spot: the faces that map to the eyes of its texture sit above the ones that map to its nose.
* **Colours** in files are sRGB-encoded (8-bit textures; PLY/OBJ vertex colours): decoded to
  linear float32 on read (:func:`ibrtools.imageio.srgb_to_linear`), encoded on write.
* **Sidecar** ``<mesh file>.attrs.npz`` (e.g. ``mesh.obj.attrs.npz``) holds what PLY and OBJ
  cannot: ``object_ids`` (M,) int32, ``materials`` (K, 2) float32 (specular, shininess) when
  present, and ``num_faces`` (a check that the sidecar belongs to the mesh). It is written
  beside the mesh when the mesh has more than one object or has materials (a stale one is
  removed otherwise) and read back by :func:`read_mesh` when present.
* **Face order**: open3d's OBJ reader (assimp) groups faces by material and splits vertices
  per (position, uv) corner. :func:`write_mesh` therefore writes OBJ faces sorted by texture
  (stably), so that reading the file back gives the faces in the written order, and the
  sidecar matches. Vertex sharing is not preserved through OBJ (the geometry is).
* Faces without texture in a textured OBJ get a 1x1 grey (0.8) texture on write.
* Polygonal OBJs (e.g. quads, as crate has) are read through open3d's tensor reader, which
  triangulates but keeps one material; triangle OBJs go through the legacy reader, which keeps
  one texture per material.

Writes are atomic: files are written in a temporary directory beside the target and renamed
into place, the mesh file last.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from ibrtools.errors import DtypeError, FormatError, MissingFileError
from ibrtools.imageio import atomic_path, linear_to_srgb, read_image, srgb8, srgb_to_linear
from ibrtools.outputs import mkdtemp_beside
from ibrtools.mesh import Mesh

MESH_EXTS = (".ply", ".obj")
SIDECAR_SUFFIX = ".attrs.npz"


def sidecar_path(path: str | os.PathLike) -> Path:
    """``<mesh file>.attrs.npz`` beside the mesh."""
    path = Path(path)
    return path.with_name(path.name + SIDECAR_SUFFIX)


def _o3d():
    import open3d as o3d  # deferred: heavy, and only mesh I/O needs it

    return o3d


def _texture_to_linear(img: np.ndarray, where: str) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise FormatError(f"{where}: texture of unexpected shape {a.shape}")
    if a.shape[2] < 3:
        a = np.repeat(a[:, :, :1], 3, axis=2)
    a = a[:, :, :3]
    if a.dtype == np.uint8:
        return np.ascontiguousarray(srgb_to_linear(a.astype(np.float32) / 255.0))
    if a.dtype == np.uint16:
        return np.ascontiguousarray(srgb_to_linear(a.astype(np.float32) / 65535.0))
    return np.ascontiguousarray(a.astype(np.float32))  # float textures are linear


def _read_legacy(path: Path) -> dict:
    o3d = _o3d()
    m = o3d.io.read_triangle_mesh(str(path), enable_post_processing=False, print_progress=False)
    faces = np.asarray(m.triangles)
    out: dict = {"vertices": np.asarray(m.vertices), "faces": faces}
    if m.has_vertex_colors():
        out["vertex_colors"] = srgb_to_linear(np.clip(np.asarray(m.vertex_colors), 0.0, 1.0))
    uvs = np.asarray(m.triangle_uvs)
    if len(faces) and len(uvs) == 3 * len(faces):
        out["uvs"] = uvs.reshape(-1, 3, 2)
        # open3d: one texture per material (empty image for a material without one).
        tex_index: dict[int, int] = {}
        textures = []
        for i, t in enumerate(m.textures):
            a = np.asarray(t)
            if a.ndim >= 2 and a.size:
                tex_index[i] = len(textures)
                textures.append(_texture_to_linear(a, str(path)))
        mat = np.asarray(m.triangle_material_ids)
        if textures:
            if len(mat) == len(faces):
                lut = np.full(max(len(m.textures), int(mat.max(initial=0)) + 1), -1, np.int32)
                for i, j in tex_index.items():
                    lut[i] = j
                out["texture_ids"] = lut[np.clip(mat, 0, len(lut) - 1)]
            else:
                out["texture_ids"] = np.zeros(len(faces), np.int32)
            out["textures"] = textures
    return out


def _read_tensor(path: Path) -> dict:
    """open3d's tensor reader: triangulates polygons; one material."""
    o3d = _o3d()
    m = o3d.t.io.read_triangle_mesh(str(path))
    if "indices" not in m.triangle or "positions" not in m.vertex:
        return {"vertices": np.zeros((0, 3)), "faces": np.zeros((0, 3), np.int64)}
    out: dict = {"vertices": m.vertex.positions.numpy(), "faces": m.triangle.indices.numpy()}
    if "colors" in m.vertex:
        c = m.vertex.colors.numpy()
        c = c.astype(np.float32) / 255.0 if c.dtype == np.uint8 else c
        out["vertex_colors"] = srgb_to_linear(np.clip(c, 0.0, 1.0))
    if "texture_uvs" in m.triangle:
        out["uvs"] = m.triangle.texture_uvs.numpy()
        if m.has_valid_material() and "albedo" in m.material.texture_maps:
            tex = m.material.texture_maps["albedo"].as_tensor().numpy()
            out["textures"] = [_texture_to_linear(tex, str(path))]
            out["texture_ids"] = np.zeros(len(out["faces"]), np.int32)
    return out


_PLY_TYPES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2,
              "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4,
              "double": 8, "float64": 8}
_PLY_NP = {1: "u1", 2: "u2", 4: "u4"}


def _check_ply(path: Path) -> None:
    """Validate a PLY's header against its body before open3d sees it.

    open3d's PLY reader (RPly underneath) crashes the process (segmentation fault) on some
    malformed files: a missing x/y/z vertex property, a face list whose count runs past the end
    of the data (found by tests/formats/test_fuzz_importers.py). It also accepts a file that holds fewer
    faces than its header announces. This check needs the header and one pass over the face
    counts (vectorised for all-triangle and all-quad files, the layouts writers produce)."""
    with open(path, "rb") as fh:
        head = fh.read(65536)
    if not head:
        raise FormatError(f"{path}: no triangles could be read (empty file)")
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise FormatError(f"{path}: not a PLY file (no 'ply' magic or no 'end_header' in the first 64 KiB)")
    nl = head.find(b"\n", end)
    body_start = (nl + 1) if nl >= 0 else len(head)
    fmt, elements = None, []
    try:
        lines = head[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise FormatError(f"{path}: PLY header is not ASCII text") from None
    for ln in lines[1:]:
        t = ln.split()
        if not t or t[0] in ("comment", "obj_info"):
            continue
        if t[0] == "format" and len(t) == 3 and t[1] in ("ascii", "binary_little_endian", "binary_big_endian"):
            fmt = t[1]
        elif t[0] == "element" and len(t) == 3 and t[2].isdigit():
            elements.append((t[1], int(t[2]), []))
        elif t[0] == "property" and elements and len(t) == 3 and t[1] in _PLY_TYPES:
            elements[-1][2].append((t[2], _PLY_TYPES[t[1]], None))
        elif (t[0] == "property" and elements and len(t) == 5 and t[1] == "list"
              and t[2] in _PLY_TYPES and t[3] in _PLY_TYPES):
            elements[-1][2].append((t[4], _PLY_TYPES[t[3]], _PLY_TYPES[t[2]]))
        else:
            raise FormatError(f"{path}: malformed PLY header line {ln[:60]!r}")
    if fmt is None:
        raise FormatError(f"{path}: PLY header has no valid 'format' line")
    el = {name: (count, props) for name, count, props in elements}
    if "vertex" not in el or {"x", "y", "z"} - {p[0] for p in el["vertex"][1]}:
        raise FormatError(f"{path}: PLY has no vertex element with properties x, y and z")
    if "face" in el and not any(p[2] is not None for p in el["face"][1]):
        raise FormatError(f"{path}: PLY face element has no list property (vertex_indices)")
    if fmt == "ascii":
        # RPly reads ASCII as a stream of tokens (line breaks do not matter): check the tokens.
        with open(path, "rb") as fh:
            fh.seek(body_start)
            tokens = fh.read().split()
        size, unit = len(tokens), "tokens"
    else:
        size, unit = path.stat().st_size - body_start, "bytes"
    order = ">" if fmt == "binary_big_endian" else "<"
    pos = 0  # in tokens (ASCII) or bytes (binary)
    with open(path, "rb") as fh:
        for name, count, props in elements:
            fixed = sum(1 if fmt == "ascii" else sz for _, sz, cs in props if cs is None)
            lists = [(sz, cs) for _, sz, cs in props if cs is not None]
            if not lists:
                pos += count * fixed
                continue
            if count == 0:
                continue
            if len(lists) != 1 or fixed:
                return  # e.g. faces with texcoord lists: not walked here, open3d reads them as before
            isz, csz = lists[0] if fmt != "ascii" else (1, 1)
            if csz not in _PLY_NP:
                raise FormatError(f"{path}: PLY element {name!r}: list count must be an integer type")
            for corners in (3, 4):  # all triangles or all quads: one vectorised check
                rec = csz + corners * isz
                if pos + count * rec > size:
                    continue
                if fmt == "ascii":
                    block = tokens[pos:pos + count * rec:rec]
                    ok = bool(np.all(np.array(block) == str(corners).encode()))
                else:
                    fh.seek(body_start + pos)
                    raw = np.frombuffer(fh.read(count * rec), np.uint8).reshape(count, rec)
                    ok = np.all(raw[:, :csz].copy().view(order + _PLY_NP[csz])[:, 0] == corners)
                if ok:
                    pos += count * rec
                    break
            else:
                raise FormatError(f"{path}: PLY element {name!r}: {count} faces announced, the data does not "
                                  "hold that many triangles or quads (truncated or corrupt; mixed polygons "
                                  "are not supported)")
    if pos > size:
        raise FormatError(f"{path}: PLY data is truncated (the header needs {pos} {unit} after it, "
                          f"the file has {size})")


def _has_polygons(path: Path) -> bool:
    """True when the OBJ has a face of more than 3 corners. (open3d's tensor reader is only
    asked then: it crashes the process on some malformed files instead of failing.)"""
    with open(path, "rb") as fh:
        for line in fh:
            if line.startswith(b"f ") and len(line.split()) > 4:
                return True
    return False


def check_mesh_path(path: str | os.PathLike) -> Path:
    """``path`` as a Path when it is a file of a mesh format :func:`read_mesh` reads
    (MissingFileError / FormatError otherwise); the file itself is not read."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: no such mesh file")
    ext = path.suffix.lower()
    if ext not in MESH_EXTS:
        raise FormatError(f"{path}: unknown mesh extension {ext!r} (expected one of {MESH_EXTS})")
    return path


def read_mesh(path: str | os.PathLike, kind: str = "ground_truth", *,
              texture: str | os.PathLike | None = None) -> Mesh:
    """Read a PLY or OBJ (+ MTL, textures) mesh, and its sidecar ``<path>.attrs.npz`` if any.

    ``texture``: an image used as the albedo of every face, for OBJs that name no texture
    (spot ships ``spot_texture.png`` without an MTL); it replaces textures from the MTL.
    """
    path = check_mesh_path(path)
    ext = path.suffix.lower()
    tex_image = None
    if texture is not None:
        tex_image = read_image(texture)  # MissingFileError / FormatError with its own message
    if ext == ".ply":
        _check_ply(path)
    o3d = _o3d()
    try:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            data = _read_legacy(path)
            if ext == ".obj" and len(data["faces"]) == 0 and _has_polygons(path):
                data = _read_tensor(path)  # polygons (quads): the legacy reader skips them
    except (RuntimeError, ValueError, OSError) as e:
        raise FormatError(f"{path}: open3d could not read the mesh ({str(e).strip().splitlines()[0]})") from None
    vertices = np.asarray(data["vertices"], dtype=np.float64)
    faces = np.asarray(data["faces"])
    if len(faces) == 0 or len(vertices) == 0:
        raise FormatError(f"{path}: no triangles could be read (empty, corrupt or not a mesh)")
    if not np.all(np.isfinite(vertices)):
        raise FormatError(f"{path}: vertices contain NaN or infinity")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise FormatError(f"{path}: a face refers to a vertex that does not exist")
    uvs = data.get("uvs")
    textures = data.get("textures", [])
    texture_ids = data.get("texture_ids")
    if tex_image is not None:
        if uvs is None:
            raise FormatError(f"{path}: texture {texture} given but the mesh has no uvs")
        textures, texture_ids = [tex_image], np.zeros(len(faces), np.int32)
    if not textures:
        texture_ids = None
    object_ids, materials = None, None
    side = sidecar_path(path)
    if side.is_file():
        try:
            with np.load(side) as z:
                n = int(z["num_faces"])
                object_ids = np.asarray(z["object_ids"], dtype=np.int32)
                materials = np.asarray(z["materials"], dtype=np.float32) if "materials" in z else None
        except Exception as e:  # noqa: BLE001 - any unreadable sidecar is a format error
            raise FormatError(f"{side}: unreadable mesh sidecar ({type(e).__name__}: {e})") from None
        if n != len(faces) or object_ids.shape != (len(faces),):
            raise FormatError(f"{side}: sidecar is for a mesh of {n} faces, {path.name} has {len(faces)}")
    return Mesh(vertices=vertices.astype(np.float32), faces=faces.astype(np.int32),
                vertex_colors=data.get("vertex_colors"), uvs=uvs, textures=textures,
                texture_ids=texture_ids, object_ids=object_ids, materials=materials, kind=kind)


def write_mesh(path: str | os.PathLike, mesh: Mesh) -> Path:
    """Write ``mesh`` as PLY (geometry, vertex colours) or OBJ (+ MTL and PNG textures), plus
    the sidecar when it has object ids or materials. PLY cannot hold textures: a textured mesh
    must go to OBJ (FormatError otherwise)."""
    path = Path(path)
    if not isinstance(mesh, Mesh):
        raise DtypeError(f"mesh: expected an ibrtools.Mesh to write to {path}, got {type(mesh).__name__}")
    ext = path.suffix.lower()
    if ext not in MESH_EXTS:
        raise FormatError(f"{path}: unknown mesh extension {ext!r} (expected one of {MESH_EXTS})")
    textured = mesh.uvs is not None and len(mesh.textures) > 0
    if ext == ".ply" and textured:
        raise FormatError(f"{path}: PLY cannot hold textures; write the textured mesh as .obj")
    o3d = _o3d()
    faces, object_ids = mesh.faces, mesh.object_ids
    m = o3d.geometry.TriangleMesh()
    m.vertices = o3d.utility.Vector3dVector(mesh.vertices.astype(np.float64))
    if mesh.vertex_colors is not None:
        m.vertex_colors = o3d.utility.Vector3dVector(linear_to_srgb(mesh.vertex_colors).astype(np.float64))
    if textured:
        tids = mesh.texture_ids if mesh.texture_ids is not None else np.zeros(len(faces), np.int32)
        textures = list(mesh.textures)
        if np.any(tids < 0):  # untextured faces: a 1x1 grey texture (the renderer's grey)
            tids = np.where(tids < 0, len(textures), tids).astype(np.int32)
            textures.append(np.full((1, 1, 3), 0.8, np.float32))
        # Faces sorted by texture: the order open3d's OBJ reader gives them back in.
        order = np.argsort(tids, kind="stable")
        faces, object_ids, tids = faces[order], object_ids[order], tids[order]
        m.triangle_uvs = o3d.utility.Vector2dVector(mesh.uvs[order].reshape(-1, 2).astype(np.float64))
        m.triangle_material_ids = o3d.utility.IntVector(tids.astype(np.int32))
        m.textures = [o3d.geometry.Image(np.ascontiguousarray(srgb8(t))) for t in textures]
    m.triangles = o3d.utility.Vector3iVector(faces.astype(np.int32))

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = mkdtemp_beside(path)
    try:
        tmp = tmp_dir / path.name
        if not o3d.io.write_triangle_mesh(str(tmp), m, write_ascii=False, compressed=False,
                                          write_vertex_normals=False, print_progress=False):
            raise FormatError(f"{path}: open3d could not write the mesh")
        # Companions (MTL, textures) first, the mesh file last: a reader that sees the mesh
        # sees it whole.
        for f in sorted(tmp_dir.iterdir()):
            if f.name != path.name:
                os.replace(f, path.parent / f.name)
        os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    side = sidecar_path(path)
    if mesh.num_objects > 1 or mesh.materials is not None or np.any(object_ids != 0):
        arrays = {"num_faces": np.int64(len(faces)), "object_ids": object_ids.astype(np.int32)}
        if mesh.materials is not None:
            arrays["materials"] = mesh.materials.astype(np.float32)
        with atomic_path(side) as tmp_side:
            with open(tmp_side, "wb") as fh:
                np.savez(fh, **arrays)
    elif side.exists():
        side.unlink()  # a sidecar of an earlier mesh would lie about this one
    return path
