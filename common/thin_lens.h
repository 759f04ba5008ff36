// Thin-lens optics (pbrt-v3 section 6.2.3) shared by the renderer's `coc`
// buffer (worker/render/camera.h) and the denoiser's adapters for other
// renderers' frames (trainer/foreign_frame.h), so both compute the circle of
// confusion the network was trained on from one formula.
#pragma once

namespace dofarm {

// Circle-of-confusion diameter in pixels of a point at view-space depth z:
//   c = 2A |z - S| / z  on the focal plane (similar triangles through the
//   lens disk of radius A focused at S), times H / (2 S tan(fov/2)) pixels
//   per scene unit there (fov vertical, H the frame's height in pixels).
// z <= 0 (a ray that escapes) gives the limit z -> infinity. 0 at A <= 0.
// Computed in double and clamped to float's range: never Inf or NaN.
float coc_diameter_pixels(float aperture_radius, float focus_distance, float tan_half_vfov,
                          int height, float z);

// The same for an orthographic camera whose view is `ortho_height` scene
// units high: every point of the lens disk looks along the viewing axis, so
// the rays through one film point meet at depth S and spread at depth z
// over 2A |z - S| / S (no 1/z: the view does not shrink with depth), at
// H / ortho_height pixels per scene unit. z <= 0 (no depth) gives the limit
// z -> infinity, which is unbounded: clamped to float's range, as are all
// values.
float ortho_coc_diameter_pixels(float aperture_radius, float focus_distance, float ortho_height,
                                int height, float z);

// Lens radius in metres of an f-number N at focal length f (mm): Blender's
// and Cycles' thin lens, radius = f / (2 N). Clamped to float's range.
float fstop_lens_radius(double focal_length_mm, double fstop);

// tan(vertical fov / 2) of a camera with focal length f (mm) on a sensor of
// width `sensor_mm` for a width x height image, as Blender fits it (sensor
// fit AUTO: the sensor spans the image's longer side).
double sensor_tan_half_vfov(double focal_length_mm, double sensor_mm, int width, int height);

}  // namespace dofarm
