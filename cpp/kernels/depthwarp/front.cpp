// The depthwarp family's front (front.h).
#include "kernels/depthwarp/front.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "ibr/errors.h"
#include "kernels/depthwarp/nbuffer.h"

namespace ibr {
namespace {

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

ImageView<float> MipView(DepthWarpMips& mm, int j, std::size_t l) {
  return ImageView<float>(mm.levels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second, 4);
}
ImageView<float> ZMipView(DepthWarpMips& mm, int j, std::size_t l) {
  return ImageView<float>(mm.zlevels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second);
}

// Levels first_level.. (1-based) of layer j; level 1 from the packed layer pv.
void FillMips(DepthWarpMips& mm, int j, const ImageView<const float>& pv, std::size_t first_level) {
  for (std::size_t l = first_level - 1; l < mm.levels[j].size(); ++l) {
    if (l == 0) {
      DepthWarpMipLevel1(pv, mm.rot[j].data(), MipView(mm, j, 0), ZMipView(mm, j, 0));
    } else {
      const ImageView<float> in = MipView(mm, j, l - 1), in_z = ZMipView(mm, j, l - 1);
      DepthWarpMipDown(ImageView<const float>(in.data, in.height, in.width, 4),
                       ImageView<const float>(in_z.data, in_z.height, in_z.width), MipView(mm, j, l), ZMipView(mm, j, l));
    }
  }
}

}  // namespace

void DepthWarpCheckPinhole(const Camera& c, const char* name) {
  if (c.model != CameraModel::kPinhole) {
    throw BadValueError(std::string(name) + ": equirect camera not supported by depthwarp (pinhole only)");
  }
}

void DepthWarpCheckDepth(const float* layers, std::int64_t n) {
  std::int64_t negative = 0, bad = 0;
  DepthWarpCountBadDepth(layers, n, &bad, &negative);  // threaded (~25 MB at L = 3, 1080p)
  if (bad || negative) {
    throw BadValueError("layers: depth must be finite and >= 0 (0 = empty), got " + std::to_string(bad) +
                        " NaN/infinite and " + std::to_string(negative) + " negative values");
  }
}

DepthWarpMotionInputs DepthWarpPrepareMotion(const float* layers, int num_layers, int height, int width,
                                             const std::int32_t* ids, const std::vector<glm::dmat4>& motions,
                                             const Camera& src, const Camera& dst) {
  DepthWarpMotionInputs in;
  in.layers = layers;
  in.ids = ids;
  in.num_layers = num_layers, in.height = height, in.width = width;
  in.num_motions = static_cast<int>(motions.size());
  if (ids) {
    const std::int64_t n = std::int64_t(num_layers) * height * width;
    std::int64_t out_of_range = 0;
    const int k = in.num_motions;
    for (std::int64_t i = 0; i < n; ++i) out_of_range += ids[i] < -1 || ids[i] >= k;
    if (out_of_range) {
      throw BadValueError("object_ids: expected -1 (static) or 0.." + std::to_string(k - 1) +
                          " (an index into object_motion), got " + std::to_string(out_of_range) +
                          " values out of range");
    }
  }
  // dst_from_src = dst.cam_from_world * motion * src.world_from_cam (3x4 row-major each).
  auto pose = [](const Camera& c) {
    glm::dmat4 m(c.rot);
    m[3] = glm::dvec4(c.trans, 1.0);
    return m;
  };
  const glm::dmat4 dst_from_world = pose(dst), world_from_src = glm::inverse(pose(src));
  auto push = [&](const glm::dmat4& a) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) in.dst_from_src.push_back(a[c][r]);
    }
  };
  push(dst_from_world * world_from_src);
  for (const glm::dmat4& t : motions) push(dst_from_world * t * world_from_src);
  return in;
}

void DepthWarpMotionLayers(const DepthWarpMotionInputs& in, const Camera& src, const Camera& dst, bool simd,
                           float* packed) {
  DepthWarpMover mover{&src, &dst, in.dst_from_src.data(), in.num_motions, simd};
  const std::int64_t plane = std::int64_t(in.height) * in.width;
  for (int j = 0; j < in.num_layers; ++j) {
    ImageView<const float> d(in.layers + j * plane, in.height, in.width);
    ImageView<const std::int32_t> idv(in.ids ? in.ids + j * plane : nullptr, in.height, in.width);
    DepthWarpMotion(d, in.ids ? &idv : nullptr, mover, ImageView<float>(packed + j * plane * 4, in.height, in.width, 4));
  }
}

void DepthWarpMips::Prepare(int nl, int hh, int ww) {
  if (num_layers == nl && height == hh && width == ww) return;
  *this = DepthWarpMips();
  num_layers = nl, height = hh, width = ww;
  levels.resize(nl);
  zlevels.resize(nl);
  dims.resize(nl);
  rot.resize(nl);
  axes.resize(nl);
  for (int j = 0; j < nl; ++j) {
    int h = hh, w = ww;
    while (h > 1 || w > 1) {
      h = (h + 1) / 2, w = (w + 1) / 2;
      dims[j].push_back({h, w});
      levels[j].emplace_back(std::size_t(h) * w * 4);
      zlevels[j].emplace_back(std::size_t(h) * w);
    }
  }
}

void DepthWarpMips::Build(const float* packed, bool oriented, int pca_grid) {
  const std::int64_t plane = std::int64_t(height) * width * 4;
  for (int j = 0; j < num_layers; ++j) {
    ImageView<const float> pv(packed + j * plane, height, width, 4);
    axes[j] = static_cast<int>(DepthWarpChooseAxes(pv, oriented, pca_grid, rot[j].data()));
    FillMips(*this, j, pv, 1);
  }
}

void DepthWarpMips::BuildWithMotion(const DepthWarpMotionInputs& in, const Camera& src, const Camera& dst,
                                    bool oriented, int pca_grid, float* packed, double* motion_ms,
                                    double* mipmap_ms) {
  DepthWarpMover mover{&src, &dst, in.dst_from_src.data(), in.num_motions};
  const std::int64_t plane = std::int64_t(in.height) * in.width;
  *motion_ms = 0, *mipmap_ms = 0;
  for (int j = 0; j < in.num_layers; ++j) {
    ImageView<const float> d(in.layers + j * plane, in.height, in.width);
    ImageView<const std::int32_t> idv(in.ids ? in.ids + j * plane : nullptr, in.height, in.width);
    const ImageView<const std::int32_t>* idp = in.ids ? &idv : nullptr;
    ImageView<float> pv(packed + j * plane * 4, in.height, in.width, 4);
    const ImageView<const float> pcv(pv.data, in.height, in.width, 4);
    auto t0 = std::chrono::steady_clock::now();
    std::size_t first = 1;
    if (!oriented && !levels[j].empty()) {
      // Axis-aligned bounds: level 1 is built in the motion pass (same results, one pass).
      rot[j] = {1.0f, 0.0f, 0.0f, 1.0f};
      axes[j] = static_cast<int>(DepthWarpAxes::kAxisAligned);
      DepthWarpMotionMipLevel1(d, idp, mover, pv, MipView(*this, j, 0), ZMipView(*this, j, 0));
      first = 2;
      *motion_ms += MsSince(t0);
      t0 = std::chrono::steady_clock::now();
    } else {
      DepthWarpMotion(d, idp, mover, pv);
      *motion_ms += MsSince(t0);
      t0 = std::chrono::steady_clock::now();
      axes[j] = static_cast<int>(DepthWarpChooseAxes(pcv, oriented, pca_grid, rot[j].data()));
    }
    FillMips(*this, j, pcv, first);
    *mipmap_ms += MsSince(t0);
  }
}

void DepthWarpCheckPcaGrid(int pca_grid) {
  if (pca_grid < 2 || pca_grid > 1024) throw BadValueError("pca_grid: expected 2..1024, got " + std::to_string(pca_grid));
}

void DepthWarpFrameOptions::Check() const {
  const DepthWarpOptions& o = warp;
  if (o.seeds < 1 || o.seeds > 4096) throw BadValueError("seeds: expected 1..4096, got " + std::to_string(o.seeds));
  if (o.iters < 0 || o.iters > 1000) throw BadValueError("iters: expected 0..1000, got " + std::to_string(o.iters));
  if (!(o.threshold > 0.0f) || !std::isfinite(o.threshold)) throw BadValueError("threshold: expected a finite number > 0");
  if (o.steps < 0 || o.steps > 64) throw BadValueError("steps: expected 0..64, got " + std::to_string(o.steps));
  if (!(o.early_exit >= 0.0f) || !std::isfinite(o.early_exit)) {
    throw BadValueError("early_exit: expected a finite number >= 0");
  }
  if (dilate_min_neighbors < 1 || dilate_min_neighbors > 8) {
    throw BadValueError("dilate_min_neighbors: expected 1..8, got " + std::to_string(dilate_min_neighbors));
  }
  if (o.tile < 1 || o.tile > kDepthWarpMaxTile) {
    throw BadValueError("tile: expected 1.." + std::to_string(kDepthWarpMaxTile) + ", got " + std::to_string(o.tile));
  }
  if (!(o.edge_motion >= 0.0f) || !std::isfinite(o.edge_motion)) {
    throw BadValueError("edge_motion: expected a finite number >= 0 (0 = off)");
  }
}

DepthWarpSeen DepthWarpMakeSeen(const Camera& src, const Camera& dst, int src_width, int src_height, int dst_width,
                                int dst_height) {
  DepthWarpCheckPinhole(src, "seen_src");
  DepthWarpCheckPinhole(dst, "seen_dst");
  if (src.width != src_width || src.height != src_height) {
    throw ShapeError("seen_src: camera is " + std::to_string(src.width) + "x" + std::to_string(src.height) +
                     " but the source layers are " + std::to_string(src_width) + "x" + std::to_string(src_height));
  }
  if (dst.width != dst_width || dst.height != dst_height) {
    throw ShapeError("seen_dst: camera size differs from dst_width x dst_height");
  }
  DepthWarpSeen seen;
  // src_from_dst = src.cam_from_world * dst.world_from_cam (rigid: world_from_cam = (R^T, -R^T t)).
  const glm::dmat3 r = src.rot * glm::transpose(dst.rot);
  const glm::dvec3 t = src.trans - r * dst.trans;
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 3; ++col) seen.src_from_dst[4 * row + col] = r[col][row];
    seen.src_from_dst[4 * row + 3] = t[row];
  }
  seen.dst_fx = dst.fx, seen.dst_fy = dst.fy, seen.dst_cx = dst.cx, seen.dst_cy = dst.cy;
  seen.src_fx = src.fx, seen.src_fy = src.fy, seen.src_cx = src.cx, seen.src_cy = src.cy;
  seen.src_width = src.width, seen.src_height = src.height;
  return seen;
}

DepthWarpFrameStats DepthWarpRenderFrame(const float* packed, const DepthWarpMips& mm, const std::int32_t* surface,
                                         const DepthWarpFrameOptions& options, int dst_height, int dst_width,
                                         float* depth_out, std::int8_t* layer_out, float* proven_out) {
  const std::int64_t plane = std::int64_t(mm.height) * mm.width * 4;
  std::vector<std::vector<ImageView<const float>>> mip_views(mm.num_layers), zmip_views(mm.num_layers);
  std::vector<DepthWarpLayer> layers(mm.num_layers);
  for (int j = 0; j < mm.num_layers; ++j) {
    for (std::size_t l = 0; l < mm.levels[j].size(); ++l) {
      mip_views[j].emplace_back(mm.levels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second, 4);
      zmip_views[j].emplace_back(mm.zlevels[j][l].data(), mm.dims[j][l].first, mm.dims[j][l].second);
    }
    layers[j].packed = ImageView<const float>(packed + j * plane, mm.height, mm.width, 4);
    layers[j].mips = mip_views[j].data();
    layers[j].zmips = zmip_views[j].data();
    layers[j].n_mips = static_cast<int>(mip_views[j].size());
    for (int i = 0; i < 4; ++i) layers[j].rot[i] = mm.rot[j][i];
  }
  const bool prove = surface != nullptr;
  if (prove) {
    const std::int64_t ids_plane = std::int64_t(mm.height) * mm.width;
    for (int j = 0; j < mm.num_layers; ++j) {
      layers[j].surface = ImageView<const std::int32_t>(surface + j * ids_plane, mm.height, mm.width);
    }
  }
  DepthWarpFrameStats stats;
  auto t0 = std::chrono::steady_clock::now();
  ImageView<float> dv(depth_out, dst_height, dst_width);
  ImageView<std::int8_t> lv(layer_out, dst_height, dst_width);
  ImageView<float> pv(prove ? proven_out : nullptr, dst_height, dst_width);
  DepthWarpBackward(layers.data(), mm.num_layers, options.warp, dv, lv, &stats.counters, prove ? &pv : nullptr);
  stats.warp_ms = MsSince(t0);
  if (options.dilate) {
    t0 = std::chrono::steady_clock::now();
    // In place, from a per-thread copy of the layers kept between calls (no fresh pages per frame).
    static thread_local std::vector<std::int8_t> l_in;
    l_in.assign(lv.data, lv.data + lv.NumPixels());
    stats.dilated = DepthWarpDilate(ImageView<const std::int8_t>(l_in.data(), dst_height, dst_width),
                                    options.dilate_min_neighbors, dv, lv);
    stats.dilate_ms = MsSince(t0);
  }
  return stats;
}

void DepthWarpForwardFrame(DepthWarpForwardKind kind, const DepthWarpMotionInputs& in, const Camera& src,
                           const Camera& dst, float* depth_out, std::int8_t* layer_out, double* motion_ms,
                           double* warp_ms) {
  auto t0 = std::chrono::steady_clock::now();
  std::vector<float> packed_buffer(std::size_t(in.num_layers) * in.height * in.width * 4);
  const float* packed = packed_buffer.data();
  DepthWarpMotionLayers(in, src, dst, true, packed_buffer.data());
  *motion_ms = MsSince(t0);
  const int dh = dst.height, dw = dst.width;
  t0 = std::chrono::steady_clock::now();
  std::vector<std::uint64_t> key(std::size_t(dh) * dw, ~std::uint64_t(0));
  ImageView<std::uint64_t> kv(key.data(), dh, dw);
  DepthWarpMover mover{&src, &dst, in.dst_from_src.data(), in.num_motions};
  const std::int64_t plane = std::int64_t(in.height) * in.width;
  for (int j = 0; j < in.num_layers; ++j) {
    ImageView<const float> d(in.layers + j * plane, in.height, in.width);
    ImageView<const std::int32_t> idv(in.ids ? in.ids + j * plane : nullptr, in.height, in.width);
    ImageView<const float> pv(packed + j * plane * 4, in.height, in.width, 4);
    DepthWarpForward(kind, d, in.ids ? &idv : nullptr, pv, mover, j, kv);
  }
  DepthWarpDecodeKeys(ImageView<const std::uint64_t>(key.data(), dh, dw), ImageView<float>(depth_out, dh, dw),
                      ImageView<std::int8_t>(layer_out, dh, dw));
  *warp_ms = MsSince(t0);
}

DepthWarpYMap::DepthWarpYMap(const float* depth, int h, int w, int mip_levels) {
  if (mip_levels < 0 || mip_levels > 8) {
    throw BadValueError("mip_levels: expected 0..8, got " + std::to_string(mip_levels));
  }
  const std::int64_t n = std::int64_t(h) * w;
  std::int64_t nan = 0;
  for (std::int64_t i = 0; i < n; ++i) nan += std::isnan(depth[i]);
  if (nan) throw BadValueError("depth: contains NaN (set holes to the far depth, or +inf, before building)");
  height_ = h, width_ = w, mip_levels_ = mip_levels;
  std::vector<float> cur(depth, depth + n);
  int ch = h, cw = w;
  for (int l = 0; l < mip_levels; ++l) {
    const int nh = (ch + 1) / 2, nw = (cw + 1) / 2;
    std::vector<float> next(std::size_t(nh) * nw);
    MaxMipDown(ImageView<const float>(cur.data(), ch, cw), ImageView<float>(next.data(), nh, nw));
    cur.swap(next);
    ch = nh, cw = nw;
  }
  ch_ = ch, cw_ = cw;
  const int top = 31 - __builtin_clz(static_cast<unsigned>(std::min(ch, cw)));  // floor(log2 min)
  nbuf_.push_back(std::move(cur));
  for (int l = 1; l <= top; ++l) {
    std::vector<float> next(std::size_t(ch) * cw);
    NBufferStep(ImageView<const float>(nbuf_.back().data(), ch, cw), 1 << (l - 1), ImageView<float>(next.data(), ch, cw));
    nbuf_.push_back(std::move(next));
  }
}

void DepthWarpYMap::MaxDepth(const std::int32_t* boxes, std::int64_t k, float* out) const {
  std::vector<ImageView<const float>> views;
  for (const auto& l : nbuf_) views.emplace_back(l.data(), ch_, cw_);
  NBufferQuery(views.data(), static_cast<int>(views.size()), mip_levels_, height_, width_, boxes, k, out);
}

}  // namespace ibr
