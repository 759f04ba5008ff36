#include "common/thin_lens.h"

#include <algorithm>
#include <cfloat>
#include <cmath>

namespace dofarm {

float coc_diameter_pixels(float aperture_radius, float focus_distance, float tan_half_vfov,
                          int height, float z) {
  if (aperture_radius <= 0) return 0;
  // In double, clamped to float's range: an extreme but valid lens or focus
  // distance (S = 1e-38) gives a huge circle, never Inf or NaN.
  const double a = aperture_radius, s = focus_distance;
  const double ratio = z > 0 ? std::fabs(double(z) - s) / z : 1.0;  // |1 - S/z|, -> 1 as z -> inf
  const double c = a * ratio * double(height) / (s * double(tan_half_vfov));
  return std::isfinite(c) ? float(std::min(c, double(FLT_MAX))) : FLT_MAX;
}

float ortho_coc_diameter_pixels(float aperture_radius, float focus_distance, float ortho_height,
                                int height, float z) {
  if (aperture_radius <= 0) return 0;
  if (!(z > 0)) return FLT_MAX;
  const double s = focus_distance;
  const double c = 2.0 * double(aperture_radius) * std::fabs(double(z) - s) / s * double(height) /
                   double(ortho_height);
  return std::isfinite(c) ? float(std::min(c, double(FLT_MAX))) : FLT_MAX;
}

float fstop_lens_radius(double focal_length_mm, double fstop) {
  // Cycles' thin lens: aperture radius = focal length / (2 N), mm -> m.
  const double r = focal_length_mm / (2.0 * fstop) * 1e-3;
  return float(std::min(r, double(FLT_MAX)));
}

double sensor_tan_half_vfov(double focal_length_mm, double sensor_mm, int width, int height) {
  // Blender: fov = 2 atan(sensor / (2 f)) across the longer side.
  const double t_longer = sensor_mm / (2.0 * focal_length_mm);
  return width >= height ? t_longer * double(height) / double(width) : t_longer;
}

}  // namespace dofarm
