// A static triangle mesh in an Embree BVH, built once and then queried by many threads
// (Embree ray queries on a committed scene are thread-safe).
//
// Works with Embree 3 (<embree3/rtcore.h>, Debian's) and Embree 4 (<embree4/rtcore.h>): the
// compile definition IBR_EMBREE_MAJOR (3 or 4, set by CMake) selects the API; the few calls
// whose signatures differ (rtcIntersect*/rtcOccluded* context vs. arguments) are wrapped here
// so that kernels never see the difference.
//
// Conventions: vertices float32 (N, 3) in world units; faces int32 (M, 3), counter-clockwise
// seen from the front; object_ids int32 (M,) (>= -1; -1 = "no object"). Embree's hit
// barycentrics (u, v) mean   p = (1 - u - v) * v0 + u * v1 + v * v2   for face (v0, v1, v2).
//
// Errors: the Embree error callback only records the first error; the front (Build, the
// checks after each commit) throws ibr::InternalError with it. Bad input (index out of
// range, non-finite vertex, empty mesh) throws ibr::BadValueError before Embree sees it.
#pragma once
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#if IBR_EMBREE_MAJOR == 4
#include <embree4/rtcore.h>
#else
#include <embree3/rtcore.h>
#endif

namespace ibr {

// BVH build choices for a static scene, measured on a 1.31 M-triangle mesh, 1920x1080 primary
// rays, 2 cores (docs/reference.md): with `robust`, quality high = medium (0.17 s build, 37 ms
// query; Embree 3 builds no spatial splits in robust mode), low is slower to trace (~7 %);
// without `robust`, high traces ~9 % faster but builds ~5x slower and is not watertight.
struct EmbreeSceneOptions {
  // RTC_BUILD_QUALITY_HIGH: SAH builder with spatial splits where the flags allow them.
  RTCBuildQuality quality = RTC_BUILD_QUALITY_HIGH;
  // RTC_SCENE_FLAG_ROBUST: watertight intersection (no ray slips between two triangles that
  // share an edge). Required by a reference renderer: a hole at an edge would be a wrong pixel.
  bool robust = true;
  // RTC_SCENE_FLAG_COMPACT: smaller BVH, slower queries. Off by default.
  bool compact = false;
};

class EmbreeScene {
 public:
  // Checks the mesh (BadValueError on empty mesh, index out of range, non-finite vertex,
  // object_ids < -1) and builds the BVH. object_ids may be null (all faces object 0).
  static std::unique_ptr<EmbreeScene> Build(const float* vertices, std::int64_t num_vertices,
                                            const std::int32_t* faces, std::int64_t num_faces,
                                            const std::int32_t* object_ids,
                                            const EmbreeSceneOptions& options = {});
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  RTCScene Handle() const { return scene_; }
  std::int64_t NumVertices() const { return static_cast<std::int64_t>(vertices_.size() / 3); }
  std::int64_t NumFaces() const { return static_cast<std::int64_t>(faces_.size() / 3); }
  // Our own copies (Embree keeps its padded buffers); row-major (N, 3) / (M, 3) / (M,).
  const float* Vertices() const { return vertices_.data(); }
  const std::int32_t* Faces() const { return faces_.data(); }
  const std::int32_t* ObjectIds() const { return object_ids_.data(); }
  std::int32_t MaxObjectId() const { return max_object_id_; }
  // Diagonal of the bounding box: the scale of ray offsets that avoid self-intersection.
  float Extent() const { return extent_; }
  double BuildMilliseconds() const { return build_ms_; }

  // Throws InternalError if Embree reported an error since the last call (and clears it).
  void ThrowIfError(const char* during) const;

 private:
  EmbreeScene() = default;
  struct ErrorLog {
    std::mutex mutex;
    bool has_error = false;
    std::string message;
  };
  static void OnError(void* user, RTCError code, const char* message);

  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
  std::vector<float> vertices_;
  std::vector<std::int32_t> faces_;
  std::vector<std::int32_t> object_ids_;
  std::int32_t max_object_id_ = -1;
  float extent_ = 0.0f;
  double build_ms_ = 0.0;
  std::unique_ptr<ErrorLog> errors_ = std::make_unique<ErrorLog>();
};

// --- Query wrappers: one spelling for Embree 3 and 4. -----------------------------------------
// A query context per thread of work; `coherent` marks primary-ray packets (camera tiles).
struct RayQuery {
#if IBR_EMBREE_MAJOR == 4
  RTCIntersectArguments intersect_args;
  RTCOccludedArguments occluded_args;
  explicit RayQuery(bool coherent) {
    rtcInitIntersectArguments(&intersect_args);
    rtcInitOccludedArguments(&occluded_args);
    const RTCRayQueryFlags flags = coherent ? RTC_RAY_QUERY_FLAG_COHERENT : RTC_RAY_QUERY_FLAG_INCOHERENT;
    intersect_args.flags = flags;
    occluded_args.flags = flags;
  }
  void Intersect1(RTCScene s, RTCRayHit* r) { rtcIntersect1(s, r, &intersect_args); }
  void Intersect8(const int* valid, RTCScene s, RTCRayHit8* r) { rtcIntersect8(valid, s, r, &intersect_args); }
  void Intersect16(const int* valid, RTCScene s, RTCRayHit16* r) { rtcIntersect16(valid, s, r, &intersect_args); }
  void Occluded1(RTCScene s, RTCRay* r) { rtcOccluded1(s, r, &occluded_args); }
#else
  RTCIntersectContext context;
  explicit RayQuery(bool coherent) {
    rtcInitIntersectContext(&context);
    context.flags = coherent ? RTC_INTERSECT_CONTEXT_FLAG_COHERENT : RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
  }
  void Intersect1(RTCScene s, RTCRayHit* r) { rtcIntersect1(s, &context, r); }
  void Intersect8(const int* valid, RTCScene s, RTCRayHit8* r) { rtcIntersect8(valid, s, &context, r); }
  void Intersect16(const int* valid, RTCScene s, RTCRayHit16* r) { rtcIntersect16(valid, s, &context, r); }
  void Occluded1(RTCScene s, RTCRay* r) { rtcOccluded1(s, &context, r); }
#endif
};

}  // namespace ibr
