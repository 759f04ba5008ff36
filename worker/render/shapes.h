// Shape builders for tests and analytic scenes. Each appends one mesh with
// its own material to a SceneData (SceneData::add_mesh) and returns the
// material index. Triangles are counter-clockwise seen from the side their
// normals point to, as in glTF, so geometric and shading normals agree.
#pragma once

#include <cstdint>

#include "worker/render/scene_data.h"

namespace dofarm::render {

// One triangle; its normal is normalize(cross(b - a, c - a)).
uint32_t add_triangle(SceneData& scene, Vec3 a, Vec3 b, Vec3 c, const Material& m);

// The quad p0 p1 p2 p3 (planar, in order around it); the normal is
// normalize(cross(p1 - p0, p3 - p0)). uv (0,0) at p0, (1,0) at p1, (1,1) at p2.
uint32_t add_quad(SceneData& scene, Vec3 p0, Vec3 p1, Vec3 p2, Vec3 p3, const Material& m);
// The parallelogram center ± u ± v, facing cross(u, v).
uint32_t add_quad(SceneData& scene, Vec3 center, Vec3 u, Vec3 v, const Material& m);

enum class Facing { kOutward, kInward };
// Axis-aligned box, 12 triangles with flat normals; kInward for a room or a
// furnace enclosure seen from inside.
uint32_t add_box(SceneData& scene, Vec3 min, Vec3 max, const Material& m,
                 Facing facing = Facing::kOutward);

// Sphere from a subdivided icosahedron: 20 * 4^subdivisions triangles.
// Smooth: vertex normals are the exact sphere normals; otherwise flat.
// Texture coordinates are spherical (u around +y, v = 0 at the top).
uint32_t add_icosphere(SceneData& scene, Vec3 center, float radius, int subdivisions,
                       const Material& m, bool smooth = true);

// Disk as a fan of `segments` triangles (its area is that of the inscribed
// polygon, (segments / 2) r^2 sin(2 pi / segments)), facing `normal`.
uint32_t add_disk(SceneData& scene, Vec3 center, Vec3 normal, float radius, int segments,
                  const Material& m);

}  // namespace dofarm::render
