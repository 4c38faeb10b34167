// Per-view meshes and their voxel tiles: see pvm.h for the contract.
#include "kernels/hybrid/pvm.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <unordered_map>

#include <tbb/parallel_sort.h>

#include "ibr/parallel.h"
#include "ibr/raster.h"

namespace ibr {
namespace {

inline bool Valid(float d) { return std::isfinite(d) && d > 0.f; }

inline bool Cut(float a, float b, float jump) { return std::fabs(a - b) > jump * std::min(a, b); }

struct GridCtx {
  const float* depth;
  const float* field;
  int h, w;
  float jump, tol;
};

inline void EmitTri(const GridCtx& c, std::int32_t a, std::int32_t b, std::int32_t d,
                    std::vector<std::int32_t>& out) {
  const float za = c.depth[a], zb = c.depth[b], zd = c.depth[d];
  if (!Valid(za) || !Valid(zb) || !Valid(zd)) return;
  if (Cut(za, zb, c.jump) || Cut(zb, zd, c.jump) || Cut(za, zd, c.jump)) return;
  out.push_back(a);
  out.push_back(b);
  out.push_back(d);
}

// One quad of vertices (x, y)..(x + 1, y + 1): a b / c d, split along the flatter diagonal.
void Quad(const GridCtx& c, int x, int y, std::vector<std::int32_t>& out) {
  const std::int32_t a = y * c.w + x, b = a + 1, cc = a + c.w, d = cc + 1;
  const float za = c.depth[a], zb = c.depth[b], zc = c.depth[cc], zd = c.depth[d];
  const bool ad_ok = Valid(za) && Valid(zd), bc_ok = Valid(zb) && Valid(zc);
  const bool use_ad = ad_ok && (!bc_ok || std::fabs(za - zd) <= std::fabs(zb - zc));
  if (use_ad) {
    EmitTri(c, a, cc, d, out);
    EmitTri(c, a, d, b, out);
  } else {
    EmitTri(c, a, cc, b, out);
    EmitTri(c, b, cc, d, out);
  }
}

// All vertices of the block valid and the planarity field within tol of the corners' bilinear.
bool Planar(const GridCtx& c, int x0, int y0, int s) {
  const float* f = c.field;
  const std::int64_t w = c.w;
  const std::int64_t ia = y0 * w + x0, ib = ia + s, ic = ia + s * w, id = ic + s;
  const double fa = f[ia], fb = f[ib], fc = f[ic], fd = f[id];
  if (!std::isfinite(fa) || !std::isfinite(fb) || !std::isfinite(fc) || !std::isfinite(fd)) return false;
  const double inv = 1.0 / s;
  for (int j = 0; j <= s; ++j) {
    const double v = j * inv;
    const double left = fa + (fc - fa) * v, right = fb + (fd - fb) * v;
    const std::int64_t row = (y0 + j) * w + x0;
    for (int i = 0; i <= s; ++i) {
      if (!Valid(c.depth[row + i])) return false;
      const double fv = f[row + i];
      const double p = left + (right - left) * (i * inv);
      if (!(std::fabs(fv - p) <= c.tol * std::fabs(fv))) return false;
    }
  }
  return true;
}

void Block(const GridCtx& c, int x0, int y0, int s, std::vector<std::int32_t>& out) {
  if (x0 >= c.w - 1 || y0 >= c.h - 1) return;
  if (s == 1) {
    Quad(c, x0, y0, out);
    return;
  }
  if (c.field != nullptr && x0 + s <= c.w - 1 && y0 + s <= c.h - 1 && Planar(c, x0, y0, s)) {
    const std::int32_t a = y0 * c.w + x0, b = a + s, cc = a + s * c.w, d = cc + s;
    out.push_back(a);
    out.push_back(cc);
    out.push_back(b);
    out.push_back(b);
    out.push_back(cc);
    out.push_back(d);
    return;
  }
  const int h = s / 2;
  Block(c, x0, y0, h, out);
  Block(c, x0 + h, y0, h, out);
  Block(c, x0, y0 + h, h, out);
  Block(c, x0 + h, y0 + h, h, out);
}

// ---- slicing ---------------------------------------------------------------------------

constexpr int kMaxPoly = 24;  // a triangle cut by six planes has at most nine vertices

struct Poly {
  std::array<double, 3> p[kMaxPoly];
  int n = 0;
};

// Keeps the part of `in` with sign * (x[axis] - value) >= 0. Each cut point is interpolated from
// the lexicographically smaller end of its edge (raster::ClipPolygon), so the two triangles sharing
// an edge get bit-identical cut points (then a tile can share them).
void ClipHalf(const Poly& in, int axis, double value, double sign, Poly& out) {
  using V = std::array<double, 3>;
  const auto d = [&](const V& v) { return sign * (v[axis] - value); };
  out.n = raster::ClipPolygon(
      in.p, in.n, out.p, [&](const V& v) { return d(v) >= 0; },
      [](const V& a, const V& b) { return std::lexicographical_compare(a.begin(), a.end(), b.begin(), b.end()); },
      [&](const V& p0, const V& p1) {
        const double d0 = d(p0), d1 = d(p1);
        const double t = d0 / (d0 - d1);
        V q;
        for (int k = 0; k < 3; ++k) q[k] = p0[k] + t * (p1[k] - p0[k]);
        q[axis] = value;  // exactly on the face, whatever the rounding of t
        return q;
      });
}

void ClipSlab(const Poly& in, int axis, double lo, double hi, Poly& tmp, Poly& out) {
  const Poly* src = &in;
  if (std::isfinite(lo)) {
    ClipHalf(*src, axis, lo, 1.0, tmp);
    src = &tmp;
  }
  if (std::isfinite(hi)) {
    ClipHalf(*src, axis, hi, -1.0, out);
  } else {
    out = *src;
  }
}

double TriArea2(const double* a, const double* b, const double* c) {
  const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  const double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  const double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2], z = u[0] * v[1] - u[1] * v[0];
  return std::sqrt(x * x + y * y + z * z);
}

constexpr std::int32_t kWhole = -1;  // the whole input triangle
constexpr std::int32_t kCopy = -2;   // the whole input triangle, one copy per cell it has area in

struct Piece {
  std::int64_t key;
  std::int64_t seq;   // position before sorting: ties keep input order (deterministic)
  std::int32_t face;
  std::int32_t clip;  // kWhole, kCopy, else index of its 9 floats in `clip`
};

// Exact bit pattern of a float32 point: cut points shared by neighbouring pieces of a tile.
struct PointKey {
  std::uint32_t b[3];
  bool operator==(const PointKey& o) const { return b[0] == o.b[0] && b[1] == o.b[1] && b[2] == o.b[2]; }
};
struct PointKeyHash {
  std::size_t operator()(const PointKey& k) const {
    std::uint64_t h = k.b[0] * 0x9E3779B97F4A7C15ull;
    h ^= (h >> 29) + k.b[1] * 0xBF58476D1CE4E5B9ull;
    h ^= (h >> 31) + k.b[2] * 0x94D049BB133111EBull;
    return static_cast<std::size_t>(h ^ (h >> 32));
  }
};

struct Chunk {
  std::vector<Piece> pieces;
  std::vector<float> clip;
};

}  // namespace

void PvmTriangulate(const float* depth, const float* plane_field, int height, int width,
                    const PvmTriangulateOptions& options, std::vector<std::int32_t>& faces) {
  if (height < 2 || width < 2) return;
  const int s = std::max(1, options.max_block);
  const GridCtx c{depth, plane_field, height, width, options.max_rel_jump, options.plane_tol};
  const int rows = (height - 1 + s - 1) / s;
  std::vector<std::vector<std::int32_t>> per_row(rows);
  ParallelFor(rows, 1, [&](std::int64_t r0, std::int64_t r1) {
    for (std::int64_t r = r0; r < r1; ++r) {
      auto& out = per_row[r];
      for (int x0 = 0; x0 < width - 1; x0 += s) Block(c, x0, static_cast<int>(r) * s, s, out);
    }
  });
  std::size_t total = faces.size();
  for (const auto& v : per_row) total += v.size();
  faces.reserve(total);
  for (const auto& v : per_row) faces.insert(faces.end(), v.begin(), v.end());
}

void PvmSlice(const float* vertices, std::int64_t num_vertices, const std::int32_t* faces,
              const std::int32_t* face_view, std::int64_t num_faces, int n_views, const PvmGrid& grid,
              bool clip_all, PvmTiles& out) {
  const int dims = grid.coarse * grid.sub;
  const int sub = grid.sub, sub3 = sub * sub * sub;
  auto cell_of = [&](int axis, double x) {
    const double t = std::floor((x - grid.origin[axis]) / grid.cell[axis]);
    return static_cast<int>(std::clamp(t, 0.0, static_cast<double>(dims - 1)));
  };
  auto key_of = [&](int i, int j, int k, int view) {
    const std::int64_t coarse_id = (static_cast<std::int64_t>(k / sub) * grid.coarse + j / sub) * grid.coarse + i / sub;
    const std::int64_t local_id = ((k % sub) * sub + (j % sub)) * sub + (i % sub);
    return (coarse_id * sub3 + local_id) * n_views + view;
  };
  auto cell_of_key = [&](std::int64_t key, int ijk[3]) {  // key_of's inverse (the view dropped)
    const std::int64_t vox = key / n_views, coarse_id = vox / sub3, local_id = vox % sub3;
    const std::int64_t c = grid.coarse;
    ijk[0] = static_cast<int>(coarse_id % c) * sub + static_cast<int>(local_id % sub);
    ijk[1] = static_cast<int>((coarse_id / c) % c) * sub + static_cast<int>((local_id / sub) % sub);
    ijk[2] = static_cast<int>(coarse_id / (c * c)) * sub + static_cast<int>(local_id / (sub * sub));
  };
  auto bound = [&](int axis, int i) {
    return grid.origin[axis] + static_cast<double>(i) * grid.cell[axis];
  };
  constexpr double kInf = std::numeric_limits<double>::infinity();

  constexpr std::int64_t kGrain = 1 << 15;
  const std::int64_t n_chunks = (num_faces + kGrain - 1) / kGrain;
  std::vector<Chunk> chunks(static_cast<std::size_t>(n_chunks));
  ParallelFor(n_chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
    for (std::int64_t ci = c0; ci < c1; ++ci) {
      Chunk& ch = chunks[ci];
      const std::int64_t f0 = ci * kGrain, f1 = std::min(num_faces, f0 + kGrain);
      ch.pieces.reserve(static_cast<std::size_t>(f1 - f0));
      Poly tri, px, py, pz, tmp;
      for (std::int64_t f = f0; f < f1; ++f) {
        const std::int32_t* fv = faces + 3 * f;
        const int view = face_view[f];
        int lo[3], hi[3];
        for (int a = 0; a < 3; ++a) {
          const double v0 = vertices[3 * fv[0] + a], v1 = vertices[3 * fv[1] + a], v2 = vertices[3 * fv[2] + a];
          lo[a] = cell_of(a, std::min({v0, v1, v2}));
          hi[a] = cell_of(a, std::max({v0, v1, v2}));
        }
        if (!clip_all) {
          // Whole, in its centroid's fine cell, when the triangle lies within the coarse cells next
          // to the centroid's (the renderer marks those visible with the centroid's: margin 1).
          int c[3];
          bool within = true;
          for (int a = 0; a < 3; ++a) {
            c[a] = cell_of(a, (static_cast<double>(vertices[3 * fv[0] + a]) + vertices[3 * fv[1] + a] +
                               vertices[3 * fv[2] + a]) / 3.0);
            within = within && lo[a] / sub >= c[a] / sub - 1 && hi[a] / sub <= c[a] / sub + 1;
          }
          if (within) lo[0] = hi[0] = c[0], lo[1] = hi[1] = c[1], lo[2] = hi[2] = c[2];
        }
        if (lo[0] == hi[0] && lo[1] == hi[1] && lo[2] == hi[2]) {
          ch.pieces.push_back({key_of(lo[0], lo[1], lo[2], view), 0, static_cast<std::int32_t>(f), kWhole});
          continue;
        }
        tri.n = 3;
        for (int k = 0; k < 3; ++k)
          for (int a = 0; a < 3; ++a) tri.p[k][a] = vertices[3 * fv[k] + a];
        const double area = TriArea2(tri.p[0].data(), tri.p[1].data(), tri.p[2].data());
        const double min_area = 1e-7 * area;
        for (int i = lo[0]; i <= hi[0]; ++i) {
          ClipSlab(tri, 0, i == 0 ? -kInf : bound(0, i), i == dims - 1 ? kInf : bound(0, i + 1), tmp, px);
          if (px.n < 3) continue;
          for (int j = lo[1]; j <= hi[1]; ++j) {
            ClipSlab(px, 1, j == 0 ? -kInf : bound(1, j), j == dims - 1 ? kInf : bound(1, j + 1), tmp, py);
            if (py.n < 3) continue;
            for (int k = lo[2]; k <= hi[2]; ++k) {
              ClipSlab(py, 2, k == 0 ? -kInf : bound(2, k), k == dims - 1 ? kInf : bound(2, k + 1), tmp, pz);
              if (pz.n < 3) continue;
              const std::int64_t key = key_of(i, j, k, view);
              if (!clip_all) {  // a copy of the whole triangle in every cell it has area in: no new vertices
                bool area_here = false;
                for (int t = 1; t + 1 < pz.n && !area_here; ++t)
                  area_here = TriArea2(pz.p[0].data(), pz.p[t].data(), pz.p[t + 1].data()) > min_area;
                if (area_here) ch.pieces.push_back({key, 0, static_cast<std::int32_t>(f), kCopy});
                continue;
              }
              for (int t = 1; t + 1 < pz.n; ++t) {
                if (!(TriArea2(pz.p[0].data(), pz.p[t].data(), pz.p[t + 1].data()) > min_area)) continue;
                ch.pieces.push_back({key, 0, static_cast<std::int32_t>(f),
                                     static_cast<std::int32_t>(ch.clip.size() / 9)});
                for (const int q : {0, t, t + 1})
                  for (int a = 0; a < 3; ++a) ch.clip.push_back(static_cast<float>(pz.p[q][a]));
              }
            }
          }
        }
      }
    }
  });

  // Concatenate in chunk order (clip indices made global), then sort by (key, seq). Each chunk
  // is copied to its place in parallel (a serial copy of lego's 23 M pieces took 1.8 s).
  std::vector<std::size_t> piece_at(chunks.size() + 1, 0), clip_at(chunks.size() + 1, 0);
  for (std::size_t ci = 0; ci < chunks.size(); ++ci) {
    piece_at[ci + 1] = piece_at[ci] + chunks[ci].pieces.size();
    clip_at[ci + 1] = clip_at[ci] + chunks[ci].clip.size();
  }
  const std::size_t n_pieces = piece_at.back();
  // Uninitialised (Piece and float are trivial): every slot is written below.
  std::unique_ptr<Piece[]> pieces(new Piece[n_pieces]);
  std::unique_ptr<float[]> clip(new float[clip_at.back()]);
  ParallelFor(n_chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
    for (std::int64_t ci = c0; ci < c1; ++ci) {
      Chunk& ch = chunks[ci];
      const std::int32_t base = static_cast<std::int32_t>(clip_at[ci] / 9);
      for (std::size_t j = 0; j < ch.pieces.size(); ++j) {
        Piece p = ch.pieces[j];
        if (p.clip >= 0) p.clip += base;
        p.seq = static_cast<std::int64_t>(piece_at[ci] + j);
        pieces[piece_at[ci] + j] = p;
      }
      std::copy(ch.clip.begin(), ch.clip.end(), clip.get() + clip_at[ci]);
      std::vector<Piece>().swap(ch.pieces);
      std::vector<float>().swap(ch.clip);
    }
  });
  const auto by_key = [](const Piece& a, const Piece& b) { return a.key != b.key ? a.key < b.key : a.seq < b.seq; };
#if defined(__SANITIZE_THREAD__)
  // ThreadSanitizer builds: TBB's sort tasks are scheduled by the uninstrumented libtbb, so every
  // element the tasks move looked racy to TSan (the kernels' tests crawled for an hour through the
  // suppression checks). (key, seq) is a strict total order, so the serial sort gives the same order.
  std::sort(pieces.get(), pieces.get() + n_pieces, by_key);
#else
  tbb::parallel_sort(pieces.get(), pieces.get() + n_pieces, by_key);
#endif

  // Assemble tiles: an input vertex is stored once per tile that uses it.
  std::vector<std::int64_t> stamp(static_cast<std::size_t>(num_vertices), -1);
  std::vector<std::int32_t> local(static_cast<std::size_t>(num_vertices), 0);
  out.vertices.clear();
  out.faces.clear();
  out.face_source.clear();
  out.keys.clear();
  out.face_offsets.assign(1, 0);
  out.vertex_offsets.assign(1, 0);
  out.bounds.clear();
  out.faces.reserve(3 * n_pieces);
  // ~1.15 vertices a piece on lego's per-view meshes (a tile shares its pieces' corners): room
  // for 1.5 saves the vector's regrowth copies (0.4 s there); it grows as before beyond that.
  out.vertices.reserve(3 * (n_pieces + n_pieces / 2));
  out.face_source.reserve(n_pieces);
  std::int64_t tile = -1;
  float* box = nullptr;
  std::unordered_map<PointKey, std::int32_t, PointKeyHash> cut_points;
  auto add_vertex = [&](const float* p) {
    for (int a = 0; a < 3; ++a) out.vertices.push_back(p[a]);
    return static_cast<std::int32_t>(out.vertices.size() / 3 - 1);
  };
  auto grow_box = [&](const float* p) {
    for (int a = 0; a < 3; ++a) {
      box[a] = std::min(box[a], p[a]);
      box[3 + a] = std::max(box[3 + a], p[a]);
    }
  };
  for (std::size_t i = 0; i < n_pieces; ++i) {
    const Piece& p = pieces[i];
    if (tile < 0 || p.key != out.keys.back()) {
      if (tile >= 0) {
        out.face_offsets.push_back(static_cast<std::int64_t>(out.faces.size() / 3));
        out.vertex_offsets.push_back(static_cast<std::int64_t>(out.vertices.size() / 3));
      }
      ++tile;
      cut_points.clear();
      out.keys.push_back(p.key);
      const float inf = std::numeric_limits<float>::infinity();
      out.bounds.insert(out.bounds.end(), {inf, inf, inf, -inf, -inf, -inf});
    }
    box = out.bounds.data() + 6 * tile;
    if (p.clip == kWhole || p.clip == kCopy) {
      float lo[3], hi[3];  // the triangle's bounds
      for (int a = 0; a < 3; ++a) lo[a] = std::numeric_limits<float>::infinity(), hi[a] = -lo[a];
      for (int k = 0; k < 3; ++k) {
        const std::int32_t v = faces[3 * static_cast<std::int64_t>(p.face) + k];
        if (stamp[v] != tile) {
          stamp[v] = tile;
          local[v] = add_vertex(vertices + 3 * static_cast<std::int64_t>(v));
        }
        out.faces.push_back(local[v]);
        for (int a = 0; a < 3; ++a) {
          lo[a] = std::min(lo[a], vertices[3 * static_cast<std::int64_t>(v) + a]);
          hi[a] = std::max(hi[a], vertices[3 * static_cast<std::int64_t>(v) + a]);
        }
      }
      if (p.clip == kCopy) {  // the tile bounds hold the copy's part in the cell (the renderer draws no more)
        int ijk[3];
        cell_of_key(p.key, ijk);
        for (int a = 0; a < 3; ++a) {
          if (ijk[a] > 0) lo[a] = std::max(lo[a], static_cast<float>(bound(a, ijk[a])));
          if (ijk[a] < dims - 1) hi[a] = std::min(hi[a], static_cast<float>(bound(a, ijk[a] + 1)));
        }
      }
      grow_box(lo);
      grow_box(hi);
    } else {
      const float* q = clip.get() + 9 * static_cast<std::int64_t>(p.clip);
      for (int k = 0; k < 3; ++k) {
        PointKey key;
        std::memcpy(key.b, q + 3 * k, sizeof key.b);
        auto it = cut_points.find(key);
        if (it == cut_points.end()) it = cut_points.emplace(key, add_vertex(q + 3 * k)).first;
        out.faces.push_back(it->second);
        grow_box(q + 3 * k);
      }
    }
    out.face_source.push_back(p.face);
  }
  if (tile >= 0) {
    out.face_offsets.push_back(static_cast<std::int64_t>(out.faces.size() / 3));
    out.vertex_offsets.push_back(static_cast<std::int64_t>(out.vertices.size() / 3));
  }
}

}  // namespace ibr
