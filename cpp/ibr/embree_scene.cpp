#include "ibr/embree_scene.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include "ibr/errors.h"

namespace ibr {
namespace {

const char* ErrorName(RTCError code) {
  switch (code) {
    case RTC_ERROR_NONE: return "no error";
    case RTC_ERROR_UNKNOWN: return "unknown error";
    case RTC_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION: return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY: return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU: return "unsupported CPU";
    case RTC_ERROR_CANCELLED: return "cancelled";
    default: return "error";
  }
}

}  // namespace

void EmbreeScene::OnError(void* user, RTCError code, const char* message) {
  // Called by Embree on any thread: record only; the front throws.
  auto* log = static_cast<ErrorLog*>(user);
  std::lock_guard<std::mutex> lock(log->mutex);
  if (log->has_error) return;
  log->has_error = true;
  log->message = std::string(ErrorName(code)) + (message ? std::string(": ") + message : std::string());
}

void EmbreeScene::ThrowIfError(const char* during) const {
  std::lock_guard<std::mutex> lock(errors_->mutex);
  if (!errors_->has_error) return;
  const std::string msg = std::string("Embree failed during ") + during + " (" + errors_->message + ")";
  errors_->has_error = false;
  errors_->message.clear();
  throw InternalError(msg);
}

std::unique_ptr<EmbreeScene> EmbreeScene::Build(const float* vertices, std::int64_t num_vertices,
                                                const std::int32_t* faces, std::int64_t num_faces,
                                                const std::int32_t* object_ids,
                                                const EmbreeSceneOptions& options) {
  // --- checks (the front: kernels trust what passes here) ---
  if (num_faces <= 0) throw BadValueError("mesh faces: the mesh has no triangles");
  if (num_vertices <= 0) throw BadValueError("mesh vertices: the mesh has no vertices");
  // Embree indexes with unsigned 32-bit ints and geometry sizes below 2^32.
  if (num_faces > std::numeric_limits<std::int32_t>::max() ||
      num_vertices > std::numeric_limits<std::int32_t>::max()) {
    throw BadValueError("mesh: more than 2^31 - 1 vertices or faces");
  }
  float lo[3] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
                 std::numeric_limits<float>::max()};
  float hi[3] = {-lo[0], -lo[1], -lo[2]};
  for (std::int64_t i = 0; i < num_vertices * 3; ++i) {
    const float v = vertices[i];
    if (!std::isfinite(v)) {
      throw BadValueError("mesh vertices: vertex " + std::to_string(i / 3) + " is NaN or infinite");
    }
    lo[i % 3] = std::min(lo[i % 3], v);
    hi[i % 3] = std::max(hi[i % 3], v);
  }
  for (std::int64_t i = 0; i < num_faces * 3; ++i) {
    if (faces[i] < 0 || faces[i] >= num_vertices) {
      throw BadValueError("mesh faces: face " + std::to_string(i / 3) + " has vertex index " +
                          std::to_string(faces[i]) + ", outside [0, " + std::to_string(num_vertices) + ")");
    }
  }
  std::int32_t max_id = 0;
  if (object_ids != nullptr) {
    max_id = -1;
    for (std::int64_t i = 0; i < num_faces; ++i) {
      if (object_ids[i] < -1) {
        throw BadValueError("object_ids: face " + std::to_string(i) + " has object id " +
                            std::to_string(object_ids[i]) + "; expected >= 0 (or -1 for none)");
      }
      max_id = std::max(max_id, object_ids[i]);
    }
  }

  std::unique_ptr<EmbreeScene> s(new EmbreeScene());
  s->vertices_.assign(vertices, vertices + num_vertices * 3);
  s->faces_.assign(faces, faces + num_faces * 3);
  if (object_ids != nullptr) s->object_ids_.assign(object_ids, object_ids + num_faces);
  else s->object_ids_.assign(static_cast<std::size_t>(num_faces), 0);
  s->max_object_id_ = max_id;
  const float dx = hi[0] - lo[0], dy = hi[1] - lo[1], dz = hi[2] - lo[2];
  s->extent_ = std::sqrt(dx * dx + dy * dy + dz * dz);

  const auto t0 = std::chrono::steady_clock::now();
  s->device_ = rtcNewDevice(nullptr);
  if (s->device_ == nullptr) {
    throw InternalError(std::string("Embree: could not create a device (") +
                        ErrorName(rtcGetDeviceError(nullptr)) + ")");
  }
  rtcSetDeviceErrorFunction(s->device_, &EmbreeScene::OnError, s->errors_.get());

  RTCGeometry geom = rtcNewGeometry(s->device_, RTC_GEOMETRY_TYPE_TRIANGLE);
  s->ThrowIfError("geometry creation");
  // Embree's own (padded, aligned) buffers: Embree may read 16 bytes past the last vertex.
  auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                         3 * sizeof(float), static_cast<std::size_t>(num_vertices)));
  auto* ib = static_cast<std::uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                 3 * sizeof(std::uint32_t),
                                                                 static_cast<std::size_t>(num_faces)));
  if (vb == nullptr || ib == nullptr) {
    rtcReleaseGeometry(geom);
    s->ThrowIfError("buffer allocation");
    throw InternalError("Embree: could not allocate the mesh buffers");
  }
  std::memcpy(vb, vertices, static_cast<std::size_t>(num_vertices) * 3 * sizeof(float));
  std::memcpy(ib, faces, static_cast<std::size_t>(num_faces) * 3 * sizeof(std::int32_t));
  rtcSetGeometryBuildQuality(geom, options.quality);
  rtcCommitGeometry(geom);

  s->scene_ = rtcNewScene(s->device_);
  int flags = RTC_SCENE_FLAG_NONE;
  if (options.robust) flags |= RTC_SCENE_FLAG_ROBUST;
  if (options.compact) flags |= RTC_SCENE_FLAG_COMPACT;
  rtcSetSceneFlags(s->scene_, static_cast<RTCSceneFlags>(flags));
  rtcSetSceneBuildQuality(s->scene_, options.quality);
  rtcAttachGeometryByID(s->scene_, geom, 0);
  rtcReleaseGeometry(geom);
  rtcCommitScene(s->scene_);
  s->ThrowIfError("BVH build");
  s->build_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return s;
}

EmbreeScene::~EmbreeScene() {
  if (scene_ != nullptr) rtcReleaseScene(scene_);
  if (device_ != nullptr) rtcReleaseDevice(device_);
}

}  // namespace ibr
