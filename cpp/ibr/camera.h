// Cameras of the engine. One convention everywhere (every kernel, binding and the Python model):
//   camera axes OpenCV: x right, y down, z forward;
//   pixel (col u, row v) has its centre at (u + 0.5, v + 0.5) in continuous image coordinates;
//   pose cam_from_world: point_in_cam = R * point_in_world + t (rigid, stored 3x4 row-major).
// Pinhole: x_img = fx * X/Z + cx, y_img = fy * Y/Z + cy; depth = Z (depth_z).
// Equirect: longitude lon grows with x_img from lon_min (left edge) to lon_max (right edge),
//   latitude lat falls with y_img from lat_max (top edge) to lat_min (bottom edge); the ray of
//   (lon, lat) is (cos lat sin lon, -sin lat, cos lat cos lon); depth = ray distance (depth_ray).
#pragma once
#include <cmath>

#include <glm/glm.hpp>

namespace ibr {

enum class CameraModel : int { kPinhole = 0, kEquirect = 1 };

struct Camera {
  CameraModel model = CameraModel::kPinhole;
  int width = 0;
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;                      // pinhole, pixels
  double lon_min = 0, lon_max = 0, lat_min = 0, lat_max = 0;  // equirect, radians
  glm::dmat3 rot{1.0};   // R of cam_from_world (column-major glm storage)
  glm::dvec3 trans{0.0}; // t of cam_from_world

  glm::dvec3 CamFromWorld(const glm::dvec3& p_world) const { return rot * p_world + trans; }
  glm::dvec3 WorldFromCamDir(const glm::dvec3& d_cam) const { return glm::transpose(rot) * d_cam; }
  glm::dvec3 CentreInWorld() const { return -(glm::transpose(rot) * trans); }

  // Ray through continuous image point (x, y), in camera axes. Pinhole: z = 1 (so that
  // t along it is z-depth); equirect: unit length (t is ray distance).
  glm::dvec3 RayInCam(double x, double y) const {
    if (model == CameraModel::kPinhole) return {(x - cx) / fx, (y - cy) / fy, 1.0};
    const double lon = lon_min + (x / width) * (lon_max - lon_min);
    const double lat = lat_max - (y / height) * (lat_max - lat_min);
    const double cl = std::cos(lat);
    return {cl * std::sin(lon), -std::sin(lat), cl * std::cos(lon)};
  }

  // Projects a point in camera axes. Returns false when it has no image position (behind a
  // pinhole camera, or at the centre). depth is z (pinhole) or distance (equirect).
  bool ProjectCam(const glm::dvec3& p, double* x, double* y, double* depth) const {
    if (model == CameraModel::kPinhole) {
      if (!(p.z > 0.0)) return false;
      *x = fx * p.x / p.z + cx;
      *y = fy * p.y / p.z + cy;
      *depth = p.z;
      return true;
    }
    const double r = glm::length(p);
    if (!(r > 0.0)) return false;
    const double lon = std::atan2(p.x, p.z);
    const double lat = std::asin(glm::clamp(-p.y / r, -1.0, 1.0));
    const double lon_span = lon_max - lon_min, lat_span = lat_max - lat_min;
    *x = (lon - lon_min) / lon_span * width;
    *y = (lat_max - lat) / lat_span * height;
    *depth = r;
    return true;
  }
};

}  // namespace ibr
