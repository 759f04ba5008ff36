// Thin-lens camera (pbrt-v3 section 6.2.3) resolved for one frame, with the
// physical circle of confusion used for the `coc` buffer. Perspective, or
// orthographic (CameraState::ortho_height > 0): parallel rays from the film
// rectangle on the near clipping plane, with a thin lens as Cycles gives
// one (the lens on that plane, each of its points looking at the film
// point's place on the focal plane, focal_distance beyond the lens).
//
// Conventions: camera space looks down -z with +y up; raster space has its
// origin at the top-left pixel corner, x right, y down. View-space depth is
// the distance along the viewing axis (positive in front of the camera).
#pragma once

#include <functional>
#include <limits>
#include <optional>
#include <string>

#include "common/image.h"
#include "common/jobspec.h"
#include "common/math.h"
#include "worker/render/scene_data.h"

namespace dofarm::render {

struct Ray {
  Vec3 o, d;  // d unit length
  // The stretch of the ray a closest-hit query searches, [t_min, t_max]
  // along d from o: everything but camera rays under a scene camera's
  // clipping planes (CameraClip) searches all of [0, inf).
  float t_min = 0.0f;
  float t_max = std::numeric_limits<float>::infinity();
};

// The scene camera's clipping planes (glTF camera.perspective znear and
// zfar; Blender's Clip Start and End): camera rays see only what lies
// between the planes at these view depths, as Cycles' camera rays do;
// light and shadow rays are not clipped. {0, inf}: no clipping.
struct CameraClip {
  float near = 0.0f;
  float far = std::numeric_limits<float>::infinity();
};

class Camera {
 public:
  Camera(const CameraState& state, int width, int height, CameraClip clip = {});

  const CameraState& state() const { return state_; }
  bool has_lens() const { return state_.aperture > 0; }
  // A ray through raster point `film`, leaving the lens at `lens` (a point of
  // [0,1)^2 mapped to the disk); `lens` is ignored for a pinhole. Its
  // [t_min, t_max] spans the view depths between the clipping planes
  // (the planes z = -near and z = -far of camera space, the lens at z = 0).
  Ray generate_ray(Vec2 film, Vec2 lens) const;
  // generate_ray() of n points at once (n <= 8: a packet): the same rays,
  // bit for bit. A perspective camera with a lens computes them in 8-wide
  // AVX2 lanes where the CPU has them (simd.h; a lane that needs
  // generate_ray()'s double-precision fallback is redone by it).
  void generate_rays(const Vec2* film, const Vec2* lens, int n, Ray* out) const;
  // The pinhole ray through `film`, whatever the aperture (aux buffers).
  Ray pinhole_ray(Vec2 film) const;
  // Circle-of-confusion diameter in pixels of a point at view-space depth z
  // (common/thin_lens.h, coc_diameter_pixels, or ortho_coc_diameter_pixels).
  // 0 at aperture 0. z <= 0 is a ray that escapes: the limit z -> infinity,
  // or for an orthographic camera, whose blur grows without bound with
  // depth, the far clipping plane's CoC (float's largest without one); its
  // focal plane lies focal_distance beyond the near clipping plane.
  float coc_pixels(float z) const;
  float view_depth(Vec3 p) const;      // along the viewing axis
  Vec3 to_view(Vec3 world_dir) const;  // rotate into camera space

 private:
  Vec3 film_direction(Vec2 film) const;  // camera space, z = -1
  Vec3 film_point(Vec2 film) const;      // orthographic: camera space, z = -near
  // An orthographic ray, which leaves the near plane, with its t range up
  // to the far plane (view_dir as for clipped()).
  Ray ortho_clipped(Ray ray, Vec3 view_dir) const;
  // ray with its t range set from the clipping planes; view_dir is its
  // direction in camera space, any length (the cosine to the viewing axis
  // is computed only where a plane clips).
  Ray clipped(Ray ray, Vec3 view_dir) const;
  // Whether a clipping plane narrows a perspective ray's [t_min, t_max].
  bool clips() const { return clip_.near > 0 || std::isfinite(clip_.far); }
  CameraState state_;
  CameraClip clip_;
  Quat rotation_, inverse_rotation_;
  Vec3 position_;
  int width_, height_;
  float tan_half_fov_, aspect_;
  float ortho_half_height_ = 0;  // > 0: orthographic
};

// ---------------------------------------------------------------------------
// The scene camera's shape (glTF camera.perspective: yfov and aspectRatio)

// The vertical field of view (degrees) that an image of width x height shows
// of a camera with vertical fov `yfov_deg` and film aspect `camera_aspect`
// (width / height; 0 = the file does not say, then yfov is vertical for any
// image, as glTF specifies). Blender's default sensor fit (AUTO): the
// camera's field of view spans the longer side of its film, and the longer
// side of whatever image it renders; the other side follows the image. This
// is what Blender's glTF exporter assumes when it writes yfov from its
// render aspect (io_scene_gltf2 gather_cameras: yfov = 2 atan(tan(angle/2) /
// aspect) for a landscape image).
float fitted_vertical_fov(float yfov_deg, float camera_aspect, int width, int height);
// The same fit for an orthographic camera (glTF camera.orthographic, xmag
// and ymag half the film's width and height): the view height, in scene
// units, that a width x height image shows of a film 2 ymag high and
// camera_aspect = xmag / ymag wide. 2 ymag when the aspects match.
float fitted_ortho_height(float ymag, float camera_aspect, int width, int height);

// The image size a job gets when its spec leaves width and/or height out
// (`width`/`height` 0 = not given): the longer side 512 when neither is
// given, the other side from the aspect (rounded, at least 1) otherwise.
struct ImageSize {
  int width = 0, height = 0;
};
ImageSize image_size_for_aspect(float camera_aspect, int width, int height);

// "" when a width x height image shows exactly the camera's film, else one
// line saying what it crops or adds, e.g. `the scene camera is 16:9 but the
// image is 512x512: it shows the camera's full width and 178% of its height`.
// `orthographic`: the camera's Orthographic Scale spans the longer side,
// not its field of view.
std::string describe_aspect_mismatch(float camera_aspect, int width, int height,
                                     bool orthographic = false);

// ---------------------------------------------------------------------------
// One frame's camera

// The view depth of what the pinhole ray through the image centre hits for
// a camera pose (focus = "auto"); nullopt when it hits nothing.
using Autofocus = std::function<std::optional<float>(const CameraState&)>;

// The camera of `frame`: keyframes of the job spec interpolated linearly
// (slerp for rotation), or the scene file's camera track when
// camera.from_scene is set (its fov fitted to the image), with the job's lens
// keys. The lens radius and focus distance of each key are resolved for this
// frame's camera (fstop -> radius, focus_point / autofocus -> distance), then
// interpolated. Throws SpecError (the key, its place in the spec, the frame)
// when camera.from_scene is set but the scene has no camera, a focus point is
// not in front of the camera, or autofocus finds nothing; `autofocus` must be
// given when a key uses focus = "auto".
CameraState camera_for_frame(const JobSpec& spec, const SceneData& scene, int frame,
                             const Autofocus& autofocus = {});

// The error text for a job with camera.from_scene whose scene (the file at
// `scene_path`) has no camera it can take: none at all, or one that
// dofarm does not render (SceneData::camera_refused says why).
std::string no_scene_camera_message(const SceneData& scene, const std::string& scene_path);

// The clipping planes of a job's camera: the scene camera's (SceneCamera's
// znear and zfar) with camera.from_scene, else none.
CameraClip camera_clip(const JobSpec& spec, const SceneData& scene);

// The time of `frame` in seconds, frame / fps: where the scene file's
// animation (camera track, moving meshes and lights) is sampled.
inline float frame_time(const JobSpec& spec, int frame) { return float(frame) / spec.fps; }

// Lens radius in scene units (metres) of an f-number: Blender/Cycles' thin
// lens, radius = focal_length / (2 N). Without a focal length it is
// sensor_width / (2 tan(fov/2)) over the image's longer side, as Blender
// relates the two (sensor fit AUTO). An orthographic camera has no focal
// length: Cycles makes its radius 1 / (2 N) scene units.
float lens_radius(const CameraKey& key, float vertical_fov_deg, int width, int height,
                  bool orthographic = false);

// Concentric square-to-disk mapping (Shirley & Chiu 1997).
Vec2 sample_concentric_disk(Vec2 u);

}  // namespace dofarm::render
