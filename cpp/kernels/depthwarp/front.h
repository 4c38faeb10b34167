// The depthwarp family's checked front (Python: ibrtools.depthwarp.core through cpp/bindings/depthwarp.cpp):
// the value checks of the kernels' inputs (they throw the typed errors of cpp/ibr/errors.h), the
// buffers (motion mipmaps, the Y-map's N-buffer pyramid), and the pipelines of a frame with their
// stage times: motion of every layer, mipmaps, backward warp + dilation, the forward baselines.
// Callable from C++ without Python; the binding only converts arrays and calls these.
// Shapes and conventions: depthwarp.h and nbuffer.h. Depth layers are (L, H, W) float32 z in the
// source camera (0 = empty), packed motion (L, H, W, 4), ids (L, H, W) int32, row-major.
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include <glm/glm.hpp>

#include "ibr/camera.h"
#include "ibr/image.h"
#include "kernels/depthwarp/depthwarp.h"

namespace ibr {

// Throws BadValueError unless the camera is pinhole (name: the argument's name in the message).
void DepthWarpCheckPinhole(const Camera& c, const char* name);

// The motion inputs of one source view: the layers and their optional object ids (borrowed), and
// dst_from_src (num_motions + 1 transforms, DepthWarpMover) composed by DepthWarpPrepareMotion.
struct DepthWarpMotionInputs {
  const float* layers = nullptr;       // (L, H, W)
  const std::int32_t* ids = nullptr;   // (L, H, W) or null
  int num_layers = 0, height = 0, width = 0;
  std::vector<double> dst_from_src;    // (num_motions + 1) x 12
  int num_motions = 0;
};

// Throws BadValueError unless every one of the n depth values is finite and >= 0.
void DepthWarpCheckDepth(const float* layers, std::int64_t n);

// Checks the ids (when given: in -1 .. K-1, K = motions.size()) and composes the transforms
// dst.cam_from_world * motion_k * src.world_from_cam. layers: checked by DepthWarpCheckDepth;
// motions: new_world_from_old_world of each object, finite and affine. Throws BadValueError.
DepthWarpMotionInputs DepthWarpPrepareMotion(const float* layers, int num_layers, int height, int width,
                                             const std::int32_t* ids, const std::vector<glm::dmat4>& motions,
                                             const Camera& src, const Camera& dst);

// The motion buffer of every layer into packed (L, H, W, 4).
void DepthWarpMotionLayers(const DepthWarpMotionInputs& in, const Camera& src, const Camera& dst, bool simd,
                           float* packed);

// Min-max motion mipmaps of every layer of a packed (L, H, W, 4) buffer (Python: _core.DepthWarpMips).
struct DepthWarpMips {
  int num_layers = 0, height = 0, width = 0;
  std::vector<std::vector<std::vector<float>>> levels;   // [layer][level - 1]: (h, w, 4)
  std::vector<std::vector<std::vector<float>>> zlevels;  // [layer][level - 1]: min z_dst (h, w)
  std::vector<std::vector<std::pair<int, int>>> dims;    // (h, w) of each level
  std::vector<std::array<float, 4>> rot;
  std::vector<int> axes;                                 // DepthWarpAxes of each layer

  // Sized for (nl, hh, ww); an object of that size keeps its buffers (no page faults when reused).
  void Prepare(int nl, int hh, int ww);
  // Axes and every level of each layer from packed (L, H, W, 4) (Prepare'd to its size).
  void Build(const float* packed, bool oriented, int pca_grid);
  // The layers' motion into packed and the mipmaps, in one pass per layer where the bounds are
  // axis-aligned (level 1 built in the motion pass: the same bits); the times of both stages.
  void BuildWithMotion(const DepthWarpMotionInputs& in, const Camera& src, const Camera& dst, bool oriented,
                       int pca_grid, float* packed, double* motion_ms, double* mipmap_ms);
};

// Throws BadValueError unless pca_grid is in 2 .. 1024.
void DepthWarpCheckPcaGrid(int pca_grid);

// The backward warp of a frame and its post-pass (Python: _core.dw_warp).
struct DepthWarpFrameOptions {
  DepthWarpOptions warp;            // the search (defaults: depthwarp.h)
  bool dilate = true;               // fill isolated holes (DepthWarpDilate)
  int dilate_min_neighbors = 5;     // converged 8-neighbours a hole needs to be filled (1..8)
  // Throws BadValueError for a value outside its range (seeds 1..4096, iters 0..1000, threshold
  // finite > 0, steps 0..64, early_exit finite >= 0, dilate_min_neighbors 1..8, tile
  // 1..kDepthWarpMaxTile, edge_motion finite >= 0).
  void Check() const;
};

// Unseen-space rejection between two pinhole cameras (DepthWarpSeen); throws ShapeError when the
// cameras' sizes are not the source layers' / the target's.
DepthWarpSeen DepthWarpMakeSeen(const Camera& src, const Camera& dst, int src_width, int src_height, int dst_width,
                                int dst_height);

struct DepthWarpFrameStats {
  DepthWarpCounters counters;
  std::int64_t dilated = 0;
  double warp_ms = 0, dilate_ms = 0;
};

// packed (L, H, W, 4) with its mipmaps; surface (L, H, W) int32 or null (then proven_out is not
// written and may be null); outputs (dst_height, dst_width).
DepthWarpFrameStats DepthWarpRenderFrame(const float* packed, const DepthWarpMips& mips, const std::int32_t* surface,
                                         const DepthWarpFrameOptions& options, int dst_height, int dst_width,
                                         float* depth_out, std::int8_t* layer_out, float* proven_out);

// The forward baselines (Python: _core.dw_forward): motion of every layer (a scratch (L, H, W, 4)),
// then each layer splatted into the target; depth (0 in holes) and layer (-1) of dst's size.
void DepthWarpForwardFrame(DepthWarpForwardKind kind, const DepthWarpMotionInputs& in, const Camera& src,
                           const Camera& dst, float* depth_out, std::int8_t* layer_out, double* motion_ms,
                           double* warp_ms);

// Y-map of a depth buffer (Python: _core.YMap; nbuffer.h): mip_levels max-mip reductions, then the
// N-buffer levels of the coarse image. The constructor checks the values (mip_levels 0..8, no NaN)
// and throws BadValueError.
class DepthWarpYMap {
 public:
  DepthWarpYMap(const float* depth, int height, int width, int mip_levels);
  // boxes (K, 4) = (x0, y0, x1, y1) int32, x1/y1 exclusive; out (K,) >= the max over each box.
  void MaxDepth(const std::int32_t* boxes, std::int64_t k, float* out) const;
  int height() const { return height_; }
  int width() const { return width_; }
  int mip_levels() const { return mip_levels_; }
  int num_nbuffer_levels() const { return static_cast<int>(nbuf_.size()); }

 private:
  int height_ = 0, width_ = 0, mip_levels_ = 0;
  std::vector<std::vector<float>> nbuf_;  // N-buffer levels of the coarse image
  int ch_ = 0, cw_ = 0;
};

}  // namespace ibr
