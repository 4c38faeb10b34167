"""The texture stage's inputs: the render mesh (mesh stage, render_edge_voxels) that the
atlas and the G-buffer use, the gain-compensated views the atlas is baked from, and the
view-dependent texture carried from the dense mesh to the render mesh (hybrid/harmonise.py
vd_at_points)."""
import numpy as np
import pytest

from ibrtools.pipeline import stages as S
from ibrtools import cache
from ibrtools.errors import BadValueError, ShapeError
from ibrtools.hybrid.globalmesh import GlobalMeshOptions, build_global_mesh, build_render_mesh
from ibrtools.hybrid.harmonise import vd_at_points
from ibrtools.raycast.reference import ReferenceRenderer
from ibrtools.synth import make_scene

SMALL = {"preset": "objects", "size": [64, 48], "views": 4, "seed": 3, "reconstructed": True,
         "holdout_targets": 1}


def test_render_mesh_is_the_same_surface_with_fewer_faces():
    scene = make_scene(**{k: v for k, v in SMALL.items() if k != "preset"}, preset="objects")
    opts = GlobalMeshOptions(max_edge_voxels=2.0, render_edge_voxels=16.0)
    dense, rec = build_global_mesh(scene, opts)
    render = build_render_mesh(scene, dense, rec["source"], opts)
    assert rec["source"] == "reconstructed"
    assert 0 < len(render.faces) < len(dense.faces)
    # Midpoint subdivision does not move the surface: the depth of both meshes agrees to float
    # rounding (relative 1e-4) wherever both are hit; the hit masks differ at most on a few
    # silhouette pixels (ray-edge ties).
    cam = scene.views[0].camera
    d1 = ReferenceRenderer(dense).render(cam, outputs="depth")["depth"]
    d2 = ReferenceRenderer(render).render(cam, outputs="depth")["depth"]
    h1, h2 = np.isfinite(d1) & (d1 > 0), np.isfinite(d2) & (d2 > 0)
    assert (h1 != h2).mean() < 0.002
    both = h1 & h2
    assert np.max(np.abs(d1[both] - d2[both]) / d1[both]) < 1e-4
    # The render mesh's vertices are vertices of the dense mesh (a coarser densification).
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(dense.vertices).query(render.vertices)
    assert dist.max() < 1e-5
    # Not coarser than the dense mesh: the dense mesh itself.
    same = build_render_mesh(scene, dense, rec["source"], GlobalMeshOptions(max_edge_voxels=2.0, render_edge_voxels=2.0))
    assert same is dense
    with pytest.raises(BadValueError, match="render_edge_voxels"):
        GlobalMeshOptions(render_edge_voxels=0.0)
    with pytest.raises(BadValueError, match="atlas_adaptive"):
        GlobalMeshOptions(atlas_adaptive="yes")
    # The atlas cap: a memory bound of 2^25 texels by default (docs/texture.md "Atlas"), at
    # most 2^30, at least 16.
    assert GlobalMeshOptions().atlas_max_texels == 2 ** 25
    GlobalMeshOptions(atlas_max_texels=2 ** 30)
    with pytest.raises(BadValueError, match="atlas_max_texels"):
        GlobalMeshOptions(atlas_max_texels=2 ** 30 + 1)
    with pytest.raises(BadValueError, match="atlas_max_texels"):
        GlobalMeshOptions(atlas_max_texels=8)


def test_fused_mesh_renders_itself():
    scene = make_scene("objects", size=(48, 36), views=3, seed=0)
    opts = GlobalMeshOptions(resolution=32)
    dense, rec = build_global_mesh(scene, opts)
    assert rec["source"] == "fusion"
    assert build_render_mesh(scene, dense, "fusion", opts) is dense


def test_vd_at_points_nearest_vertex_and_bad_input():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    vd = np.array([0.1, 0.5, 0.9], np.float32)
    out = vd_at_points(v, vd, np.array([[0.9, 0.05, 0], [0, 0, 0], [0.1, 0.8, 0]]))
    assert out.dtype == np.float32 and out.tolist() == pytest.approx([0.5, 0.1, 0.9])
    assert vd_at_points(v, vd, np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ShapeError):
        vd_at_points(v, vd[:2], v)
    with pytest.raises(ShapeError):
        vd_at_points(v[:, :2], vd, v)
    with pytest.raises(ShapeError):
        vd_at_points(v, vd, np.zeros((3, 2)))
    with pytest.raises(ShapeError):
        vd_at_points(np.zeros((0, 3)), np.zeros(0, np.float32), v)


def _atlas(tmp_path, name, jitter):
    d = tmp_path / name
    S.preprocess("synth:objects", d, synth={**SMALL, "exposure_jitter": jitter}, methods=["tm"],
                 stage_options={"mesh": {"max_edge_voxels": 8.0}})
    from ibrtools.imageio import srgb_to_linear

    tex = cache.load_npz(cache.stage_output(d, "texture"))
    mesh = cache.load_npz(cache.stage_output(d, "mesh"))
    # The stage stores 8-bit sRGB RGBA (atlas.to_srgb8): decoded to linear RGB for the comparison.
    assert tex["atlas"].dtype == np.uint8 and tex["atlas"].shape[2] == 4
    tex["atlas"] = srgb_to_linear(tex["atlas"][..., :3].astype(np.float32) / 255.0)
    return tex, mesh, d


def test_texture_stage_bakes_gain_compensated_views_on_the_render_mesh(tmp_path):
    ref, mesh, d = _atlas(tmp_path, "plain", 0.0)
    jit, _, dj = _atlas(tmp_path, "jittered", 0.3)
    # The atlas belongs to the render mesh (fewer faces than the dense mesh).
    assert "render_faces" in mesh and len(mesh["render_faces"]) < len(mesh["faces"])
    assert ref["uv"].shape == (len(mesh["render_faces"]), 3, 2)
    assert ref["vertex_colors"].shape == (len(mesh["render_vertices"]), 3)
    # Per-view exposure jitter of sigma 0.3 in log (gains 0.55-1.8 over 4 views): with the global
    # gains divided out, the atlas of the jittered scene stays within a few per cent of the
    # unjittered one on average (what remains: the gains are normalised to geometric mean 1 over
    # the views, so one common factor, and the blend weights). Without compensation the
    # per-view blend of gains 0.55-1.8 moves the atlas by tens of per cent.
    used = ref["atlas"].sum(-1) > 0
    ratio = np.median(jit["atlas"][used] / np.maximum(ref["atlas"][used], 1e-3), axis=0)
    spread = np.percentile(np.abs(np.log(np.maximum(jit["atlas"][used], 1e-3) / np.maximum(ref["atlas"][used], 1e-3))
                                  - np.log(ratio)), 75)
    assert spread < 0.05, (ratio, spread)
    # The estimated gains: spread (max - min of the log gains) well above that of the
    # unjittered scene, where glossy objects and small images leave a few per cent.
    spread_jit = cache.read_doc(dj)["stages"]["texture"]["details"]["gain_spread"]
    spread_ref = cache.read_doc(d)["stages"]["texture"]["details"]["gain_spread"]
    assert spread_ref < 0.1 and spread_jit > 3 * spread_ref + 0.2, (spread_ref, spread_jit)
    # The gain model (hybrid/gainmodel.py, default "auto"): independent jitter is exposure, and
    # the stage divides the gains out as they are (the 4 views' leave-one-out residual ratio is
    # far above gain_max_ratio 0.5).
    rec_jit = cache.read_doc(dj)["stages"]["texture"]["details"]
    assert rec_jit["gain_model"] == "exposure" and rec_jit["gain_ratio"] > 0.5, rec_jit
    # A reconstructed mesh keeps k_views / bake_normal_rounds (4, 0); a fused one would take
    # fused_k_views / fused_normal_rounds (GlobalMeshOptions.texture_options).
    assert (rec_jit["k_views"], rec_jit["normal_rounds"]) == (4, 0), rec_jit


def test_texture_options_by_mesh_source():
    o = GlobalMeshOptions(k_views=3, bake_normal_rounds=1, fused_k_views=6, fused_normal_rounds=5)
    for src in ("reconstructed", "ground_truth"):
        assert o.texture_options(src) is o
    f = o.texture_options("fusion")
    assert (f.k_views, f.bake_normal_rounds) == (6, 5)
    assert {k: v for k, v in f.to_dict().items() if k not in ("k_views", "bake_normal_rounds")} == \
        {k: v for k, v in o.to_dict().items() if k not in ("k_views", "bake_normal_rounds")}
    d = GlobalMeshOptions().texture_options("fusion")
    assert (d.k_views, d.bake_normal_rounds) == (8, 8)
    with pytest.raises(BadValueError, match="fused_k_views"):
        GlobalMeshOptions(fused_k_views=0)
    with pytest.raises(BadValueError, match="fused_normal_rounds"):
        GlobalMeshOptions(fused_normal_rounds=-1)
