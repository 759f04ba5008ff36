// Thin-lens camera (pbrt-v3 section 6.2.3) resolved for one frame, with the
// physical circle of confusion used for the `coc` buffer.
//
// Conventions: camera space looks down -z with +y up; raster space has its
// origin at the top-left pixel corner, x right, y down. View-space depth is
// the distance along the viewing axis (positive in front of the camera).
#pragma once

#include "common/image.h"
#include "common/jobspec.h"
#include "common/math.h"
#include "worker/render/scene_data.h"

namespace dofarm::render {

struct Ray {
  Vec3 o, d;  // d unit length
};

class Camera {
 public:
  Camera(const CameraState& state, int width, int height);

  const CameraState& state() const { return state_; }
  bool has_lens() const { return state_.aperture > 0; }
  // A ray through raster point `film`, leaving the lens at `lens` (a point of
  // [0,1)^2 mapped to the disk); `lens` is ignored for a pinhole.
  Ray generate_ray(Vec2 film, Vec2 lens) const;
  // The pinhole ray through `film`, whatever the aperture (aux buffers).
  Ray pinhole_ray(Vec2 film) const;
  // Circle-of-confusion diameter in pixels of a point at view-space depth z:
  //   c = 2A |z - S| / z  on the focal plane (similar triangles through the
  //   lens disk of radius A focused at S), times H / (2 S tan(fov/2)) pixels
  //   per scene unit there. z <= 0 (a ray that escapes) gives the limit
  //   z -> infinity. 0 at aperture 0.
  float coc_pixels(float z) const;
  float view_depth(Vec3 p) const;      // along the viewing axis
  Vec3 to_view(Vec3 world_dir) const;  // rotate into camera space

 private:
  Vec3 film_direction(Vec2 film) const;  // camera space, z = -1
  CameraState state_;
  Quat rotation_, inverse_rotation_;
  Vec3 position_;
  int width_, height_;
  float tan_half_fov_, aspect_;
};

// The camera of `frame`: keyframes of the job spec interpolated linearly
// (slerp for rotation), or the scene file's camera track when
// camera.from_scene is set, with the job's lens keys.
CameraState camera_for_frame(const JobSpec& spec, const SceneData& scene, int frame);

// Concentric square-to-disk mapping (Shirley & Chiu 1997).
Vec2 sample_concentric_disk(Vec2 u);

}  // namespace dofarm::render
