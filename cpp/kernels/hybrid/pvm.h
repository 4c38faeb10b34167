// Per-view meshes (PVM) and their two-level voxel tiles (Prakash et al. 2021, sec. 5.1 and
// Fig. 2b; Hedman et al. 2016 sec. 4 for the per-view meshes).
//
// PvmTriangulate: the visible surface of one view as triangles over its pixel grid.
//   Vertices are the pixel centres (x + 0.5, y + 0.5) of an (H, W) depth map; vertex id = y * W + x.
//   A depth is valid when finite and > 0. Quadtree over blocks of `max_block` (a power of two)
//   quads, block (x0, y0, s) covering vertices x0..x0+s, y0..y0+s:
//   * merged into 2 triangles when s > 1, the block lies fully inside the image, all its vertices
//     are valid, and the planarity field f (1/z for a pinhole camera: affine in the pixel
//     coordinates exactly when the surface is a plane) departs from the bilinear interpolation
//     of its 4 corners by at most plane_tol * f at every vertex of the block. Neighbouring blocks
//     of different sizes meet at T-junctions whose vertices lie on the merged edge within that
//     tolerance, so cracks are at most plane_tol of the depth wide (docs/preprocess.md).
//   * else split into 4 (s > 1), or, for a single quad, up to 2 triangles split along the
//     diagonal with the smaller depth difference; a triangle is kept only when its 3 vertices are
//     valid and none of its 3 edges is cut. An edge (a, b) is cut at a depth discontinuity:
//     |d_a - d_b| > max_rel_jump * min(d_a, d_b).
//   plane_field == nullptr disables merging (equirect views). Triangles are counter-clockwise
//   seen from the camera (outward normal towards it), as mesh.py wants.
//   Output: faces (3 vertex ids each) appended to `faces`, block rows in order (the partition
//   depends only on H, W and max_block, so the output is identical for any thread count).
//
// PvmSlice: triangles (world space) sliced into the fine cells of a two-level grid.
//   The fine grid has dims[a] = coarse[a] * sub cells along axis a, cell (i, j, k) spanning
//   origin + (i, j, k) * cell .. + cell; the outermost cells extend to infinity so every
//   triangle is covered. A triangle inside one cell is kept whole (by vertex ids). One that
//   crosses cells:
//   * default: kept whole, in the fine cell of its centroid, when it lies within the coarse cells
//     next to (or at) its centroid's coarse cell (the renderer marks visible the coarse cells
//     within a margin of 1 around those its G-buffer hits, so the tile is ranked wherever a part
//     of the triangle can be seen); else whole in each fine cell it has area in, a copy per cell,
//     the tile's bounds holding only the copy's part in the cell (the renderer draws a tile's
//     triangles within its bounds' projection: the same fragments as clipped pieces, where
//     copies overlap drawn twice, a view keeps its nearest). No new vertices, so no T-junctions
//     between neighbouring triangles.
//   * clip_all (the paper's slicing; 3.8 x the triangles of lego's per-view meshes): clipped
//     (Sutherland-Hodgman against the cell's slabs) into polygons, fanned into triangles.
//   Pieces of area below 1e-7 of the triangle's are dropped (slivers from a vertex exactly on a
//   cell face; with the default, a cell where all of them are that small gets no copy). Each
//   piece's tile key is
//     key = (coarse_id * sub^3 + local_id) * n_views + view,
//     coarse_id = (cz * coarse + cy) * coarse + cx, local_id = (lz * sub + ly) * sub + lx,
//   so sorting by key groups tiles by coarse cell, then fine cell, then view.
//   Output: PvmTiles (below); tiles sorted by key, faces of a tile contiguous, vertices of a tile
//   contiguous and shared by its faces (an input vertex appears once per tile that uses it; cut
//   points are computed from the lexicographically smaller end of an edge, so the pieces of two
//   triangles sharing an edge get bit-identical cut points, stored once per tile).
//
// The fronts (cpp/bindings/hybrid.cpp) check shapes, index ranges and finiteness; kernels trust
// their inputs and never throw. Results are identical for any thread count.
#pragma once
#include <cstdint>
#include <vector>

namespace ibr {

struct PvmTriangulateOptions {
  float max_rel_jump = 0.03f;  // edge cut above this relative depth jump
  float plane_tol = 1e-3f;     // relative planarity tolerance of a merged block
  int max_block = 16;          // largest merged block in quads (power of two)
};

void PvmTriangulate(const float* depth, const float* plane_field, int height, int width,
                    const PvmTriangulateOptions& options, std::vector<std::int32_t>& faces);

struct PvmGrid {
  double origin[3];  // world min corner
  double cell[3];    // fine cell size per axis (> 0)
  int coarse;        // coarse cells per axis (32)
  int sub;           // fine cells per coarse cell per axis (4)
};

struct PvmTiles {
  std::vector<float> vertices;             // (V, 3) world
  std::vector<std::int32_t> faces;         // (F, 3) indices into vertices
  std::vector<std::int32_t> face_source;   // (F,) input face each piece comes from
  std::vector<std::int64_t> keys;          // (T,) tile keys, ascending
  std::vector<std::int64_t> face_offsets;  // (T + 1,)
  std::vector<std::int64_t> vertex_offsets;  // (T + 1,)
  std::vector<float> bounds;               // (T, 2, 3) AABB of each tile's triangles (a copy's: its part in the cell)
};

// vertices (N, 3), faces (M, 3), face_view (M,) in [0, n_views).
void PvmSlice(const float* vertices, std::int64_t num_vertices, const std::int32_t* faces,
              const std::int32_t* face_view, std::int64_t num_faces, int n_views, const PvmGrid& grid,
              bool clip_all, PvmTiles& out);

}  // namespace ibr
