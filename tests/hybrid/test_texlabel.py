"""One view per face for the texture bake (ibrtools.hybrid.texlabel, atlas.bake with
bake_label_weight): face adjacency against a set-based reference, alpha-expansion against
brute-force minima on small graphs, the projected-area data term (closer and frontal views
cheaper, back-facing / occluded views excluded), a labelled bake that takes one view's colour
where the per-texel blend mixes two, bad input."""
import itertools

import numpy as np
import pytest

from conftest import wall
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, ShapeError
from ibrtools.hybrid import atlas as A
from ibrtools.hybrid.globalmesh import (GlobalMeshOptions, densify, depth_from_mesh, point_colors, vertex_colors,
                                        vertex_normals)
from ibrtools.hybrid.texlabel import UNSEEN_COST, face_data_cost, face_edges, potts_energy, potts_labels


def cam_at(eye, w=48, h=48, f=48.0):
    return Camera.pinhole(w, h, f, f, w / 2, h / 2, look_at(eye, (0.0, 0.0, 2.0), up=(0.0, -1.0, 0.0)))


def test_face_edges_against_sets():
    mesh = densify(wall(), 0.5)
    got = face_edges(mesh.faces)
    ref = set()
    for i, j in itertools.combinations(range(len(mesh.faces)), 2):
        if len(set(mesh.faces[i].tolist()) & set(mesh.faces[j].tolist())) == 2:
            ref.add((i, j))
    assert sorted(map(tuple, got.tolist())) == sorted(ref)
    assert face_edges(np.zeros((0, 3), np.int32)).shape == (0, 2)


@pytest.mark.parametrize("labels", [2, 3])
def test_potts_labels_against_brute_force(labels):
    """Two labels: one expansion is an exact binary min-cut, so alpha-expansion finds the global
    minimum. Three labels: a local minimum within 2x of the global one (Boykov et al.), here
    checked against every labelling of small graphs (a 3x3 grid with diagonals, a 9-cycle)."""
    rng = np.random.default_rng(labels)
    grid = [(r * 3 + c, r * 3 + c + 1) for r in range(3) for c in range(2)]
    grid += [(r * 3 + c, (r + 1) * 3 + c) for r in range(2) for c in range(3)]
    grid += [(r * 3 + c, (r + 1) * 3 + c + 1) for r in range(2) for c in range(2)]
    cycle = [(i, (i + 1) % 9) for i in range(9)]
    for edges in (np.array(grid), np.array(cycle)):
        for trial in range(6):
            cost = rng.random((9, labels))
            w = [0.1, 0.3, 0.6][trial % 3]
            lab = potts_labels(cost, edges, w, sweeps=5)
            best = min(potts_energy(cost, edges, np.array(lb), w) for lb in itertools.product(range(labels), repeat=9))
            e = potts_energy(cost, edges, lab, w)
            start = potts_energy(cost, edges, cost.argmin(1), w)
            assert e <= start + 1e-12
            if labels == 2:
                assert e == pytest.approx(best, abs=1e-9)
            else:
                assert best - 1e-9 <= e <= 2 * best + 1e-9


def test_potts_labels_smooths_a_noisy_choice():
    # A chain of 200 faces whose best view flips at random between two nearly equal costs, with
    # one clear change of view in the middle: a Potts weight leaves two runs.
    rng = np.random.default_rng(0)
    n = 200
    cost = np.zeros((n, 2))
    cost[: n // 2, 1] = 0.2
    cost[n // 2:, 0] = 0.2
    cost += rng.normal(0, 0.15, cost.shape)
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    assert (np.diff(cost.argmin(1)) != 0).sum() > 10
    lab = potts_labels(cost, edges, 1.0)
    assert (np.diff(lab) != 0).sum() == 1 and lab[0] == 0 and lab[-1] == 1
    assert np.array_equal(potts_labels(cost, edges, 0.0), cost.argmin(1))


def test_face_data_cost():
    mesh = densify(wall(), 0.5)
    near, far = cam_at((0.0, 0.0, 0.5)), cam_at((0.0, 0.0, -1.0))
    behind = Camera.pinhole(48, 48, 48.0, 48.0, 24, 24, look_at((0.0, 0.0, 4.0), (0.0, 0.0, 2.0), up=(0.0, -1.0, 0.0)))
    cams = {"near": near, "far": far, "behind": behind}
    deps = depth_from_mesh(mesh, cams)
    deps["behind"] = np.full((48, 48), 2.0, np.float32)  # would pass the depth test: back-facing excludes it
    cost = face_data_cost(mesh, cams, deps)
    seen_near = cost[:, 0] < UNSEEN_COST
    assert seen_near.any() and (cost[:, 2] == UNSEEN_COST).all()
    # Where both see a face, the near view projects it larger: cost 0; the far view (3x the
    # distance: 1/9 of the area) costs 1 - 1/9.
    both = seen_near & (cost[:, 1] < UNSEEN_COST)
    assert both.any()
    np.testing.assert_allclose(cost[both, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(cost[both, 1], 1 - (1.5 / 3.0) ** 2, atol=0.02)
    # Occluded (the view's depth much nearer than the face): excluded.
    occ = dict(deps, far=np.where(deps["far"] > 0, 1.0, 0.0).astype(np.float32))
    assert (face_data_cost(mesh, cams, occ)[:, 1] == UNSEEN_COST).all()


def test_labelled_bake_takes_one_view():
    mesh = densify(wall(), 0.25)
    a, b = cam_at((0.0, 0.0, 0.8)), cam_at((0.3, 0.0, 0.0))
    cams = {"a": a, "b": b}
    deps = depth_from_mesh(mesh, cams)
    cols = {"a": np.full((48, 48, 3), [0.8, 0.1, 0.1], np.float32),
            "b": np.full((48, 48, 3), [0.1, 0.8, 0.1], np.float32)}
    lay = A.layout(mesh, texel=0.05)
    vc, _ = vertex_colors(mesh, cams, cols, deps)
    blend, _ = A.bake(mesh, lay, cams, cols, deps, vc)
    one, _ = A.bake(mesh, lay, cams, cols, deps, vc, GlobalMeshOptions(bake_label_weight=1.0))
    used = lay.face_of_texel >= 0
    cost = face_data_cost(mesh, cams, deps)
    lab = potts_labels(cost, face_edges(mesh.faces), 1.0)
    face_a = (lab == 0) & (cost[:, 0] < UNSEEN_COST)
    texel_a = used & face_a[np.maximum(lay.face_of_texel, 0)]
    # The closer view a wins the faces it sees well; their texels that a sees (not all: a face
    # whose centroid a sees may reach past a's image border; those keep the per-texel blend) are
    # a's colour exactly (a constant image: bilinear sampling returns it); the blend mixes a and b.
    (ys, xs, face), _, pts, nrm = A.texel_points(mesh, lay, vertex_normals(mesh.vertices, mesh.faces))
    _, seen_a = point_colors(pts, nrm, {"a": a}, {"a": cols["a"]}, {"a": deps["a"]})
    sa = np.zeros_like(used)
    sa[ys, xs] = seen_a > 0
    texel_a &= sa
    assert texel_a.sum() > 0.3 * used.sum()
    np.testing.assert_allclose(one[texel_a], np.broadcast_to([0.8, 0.1, 0.1], one[texel_a].shape), atol=1e-6)
    assert np.abs(blend[texel_a] - [0.8, 0.1, 0.1]).max(1).mean() > 0.05
    # No texel that a view sees holds a mix of the two colours.
    _, seen_any = point_colors(pts, nrm, cams, cols, deps)
    s_any = np.zeros_like(used)
    s_any[ys, xs] = seen_any > 0
    d = np.minimum(np.abs(one[s_any] - [0.8, 0.1, 0.1]).max(1), np.abs(one[s_any] - [0.1, 0.8, 0.1]).max(1))
    assert d.max() < 1e-6


def test_bad_input():
    e = np.array([[0, 1]])
    with pytest.raises(ShapeError):
        potts_labels(np.zeros(3), e, 1.0)
    with pytest.raises(BadValueError, match="finite"):
        potts_labels(np.full((2, 2), np.nan), e, 1.0)
    with pytest.raises(ShapeError):
        potts_labels(np.zeros((2, 2)), np.zeros((1, 3), np.int64), 1.0)
    with pytest.raises(BadValueError, match="face index"):
        potts_labels(np.zeros((2, 2)), np.array([[0, 2]]), 1.0)
    with pytest.raises(BadValueError, match="weight"):
        potts_labels(np.zeros((2, 2)), e, -1.0)
    with pytest.raises(BadValueError, match="sweeps"):
        potts_labels(np.zeros((2, 2)), e, 1.0, sweeps=0)
    with pytest.raises(ShapeError):
        face_edges(np.zeros((2, 2), np.int32))
    mesh = wall()
    c = cam_at((0.0, 0.0, 0.0))
    with pytest.raises(BadValueError, match="no views"):
        face_data_cost(mesh, {}, {})
    with pytest.raises(ShapeError):
        face_data_cost(mesh, {"c": c}, {"c": np.zeros((3, 3), np.float32)})
    with pytest.raises(BadValueError, match="depth_tol"):
        face_data_cost(mesh, {"c": c}, {"c": np.zeros((48, 48), np.float32)}, depth_tol=0.0)
    with pytest.raises(BadValueError, match="pinhole"):
        face_data_cost(mesh, {"e": Camera.equirect(32, 16)}, {"e": np.zeros((16, 32), np.float32)})
    with pytest.raises(BadValueError, match="bake_label_weight"):
        GlobalMeshOptions(bake_label_weight=-1.0)
