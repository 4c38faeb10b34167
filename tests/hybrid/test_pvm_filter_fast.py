"""The spatial filter of Eq. 1 (cpp/kernels/hybrid/pvm_render.cpp PvmFilter) on its four-lane path
(ExpNeg4): two clusters whose depths differ by less than the falloff scale, so that the
cross-cluster exponentials are far from 0 and 1 and the weight ratio has a closed form; the
filter_step and alpha values vary the window and the exponent arguments."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools.camera import Camera, look_at
from ibrtools.hybrid.pvm import build_tiles
from ibrtools.hybrid.pvm_render import PvmRenderer
from ibrtools.scene import Scene, View


def _two_plane_scene(near=3.0, far=3.1, w=48, h=32):
    """Three identical cameras: view 0 sees a plane at `near` (colour 0.9), views 1 and 2 one at
    `far` (colour 0.2). Every pixel has a near cluster of 1 candidate and a far one of 2."""
    cams = [Camera.from_fov(w, h, 50.0, look_at((0.0, 0.0, 0.0), (0.0, 0.0, 5.0))) for _ in range(3)]
    depths = [np.full((h, w), d, np.float32) for d in (near, far, far)]
    colors = [np.full((h, w, 3), c, np.float32) for c in (0.9, 0.2, 0.2)]
    views = [View.create(f"v{i}", c, color=col, depth=d) for i, (c, col, d) in enumerate(zip(cams, colors, depths))]
    scene = Scene(views=views, targets=[], paths={}, meshes={}, units="m", source={})
    return scene, cams[0]


@pytest.mark.parametrize("alpha,step", [(7.0, 2), (7.0, 1), (2.5, 2), (20.0, 3)])
def test_eq1_weight_ratio_with_overlapping_falloff(alpha, step):
    """Inside the window (all neighbours hold both clusters, same depths), Eq. 1 gives
    W_far / W_near = (2 + e) / (1 + 2 e) with e = exp(-alpha |far - near|) whatever the Gaussian,
    and the colour a c_far + (1 - a) c_near with a = R^gamma / (1 + R^gamma). Tolerance 5e-5:
    measured up to 1.7e-5 from the closed form at alpha 7 (the 7th power amplifies the float
    rounding of the candidates' depths and of the sums); the scalar loop this path replaced gave
    the same colours within 2e-7 on this scene (A/B of the two builds, docs/pvm_render.md)."""
    near, far, gamma = 3.0, 3.1, 7.0
    scene, cam = _two_plane_scene(near, far)
    tiles = build_tiles({v.name: v.camera for v in scene.views}, {v.name: v.depth for v in scene.views})
    r = PvmRenderer(scene, {"alpha": alpha, "gamma": gamma, "filter_step": step, "merge_rel": 0.02},
                    tiles=tiles, images={v.name: v.color for v in scene.views})
    res = r.render(cam, filtered=True)
    e = np.exp(-alpha * (far - near))
    ratio = (2 + e) / (1 + 2 * e)
    a = ratio**gamma / (1 + ratio**gamma)
    inner = np.zeros(res.valid.shape, bool)
    inner[8:-8, 8:-8] = True  # farther than the 13 x 13 (or 19 x 19 at step 3) window's radius from the border
    assert res.valid[inner].all() and (res.vote[inner] < 1).all()
    np.testing.assert_allclose(res.color[inner], a * 0.2 + (1 - a) * 0.9, atol=5e-5)
    assert np.isfinite(res.color).all()


def test_eq1_far_apart_clusters_do_not_mix():
    """|far - near| = 2, alpha = 50: exp(-100) is beyond ExpNeg's cut (87), exactly 0; the
    ratio is 2 and the blend weight 2^7 / (1 + 2^7)."""
    scene, cam = _two_plane_scene(3.0, 5.0)
    tiles = build_tiles({v.name: v.camera for v in scene.views}, {v.name: v.depth for v in scene.views})
    r = PvmRenderer(scene, {"alpha": 50.0}, tiles=tiles, images={v.name: v.color for v in scene.views})
    res = r.render(cam, filtered=True)
    a = 2.0**7 / (1 + 2.0**7)
    np.testing.assert_allclose(res.color[8:-8, 8:-8], a * 0.2 + (1 - a) * 0.9, atol=1e-5)
