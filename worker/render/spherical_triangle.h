// Sampling a triangle light by the solid angle it subtends.
//
// Next-event estimation that picks a point uniformly by area weighs it by
// r^2 / cos(theta_light), which has no bound for a receiver close to the
// light (the ceiling and walls beside a ceiling lamp, a surface under a light
// that hangs millimetres below it): a few shadow rays that land near the
// receiver carry huge values. Sampling the triangle's spherical projection
// uniformly gives every direction the same weight, 1 / solid angle, which is
// bounded by the triangle's size as seen from the receiver.
//
// - Solid angle: Van Oosterom and Strackee, "The solid angle of a plane
//   triangle", IEEE Trans. Biomed. Eng. 30(2), 1983:
//   tan(Omega / 2) = |a . (b x c)| / (1 + a.b + b.c + c.a) for unit a, b, c.
// - Sampling: Arvo, "Stratified sampling of spherical triangles", SIGGRAPH
//   1995 (section 3): a sub-triangle of area u1 * Omega is cut off by a
//   point C' on the arc AC, then the point is placed on the arc BC' by u2.
//   The map from (u1, u2) is continuous and area preserving, so stratified
//   (Sobol') points stay stratified on the sphere.
//
// Both are computed in double: the edges of a small or distant triangle are
// nearly parallel directions.
#pragma once

#include "common/math.h"

namespace dofarm::render {

// Solid angle of the triangle with vertices a, b, c as seen from `from`
// (either winding); 0 for a point in the triangle's plane or a degenerate
// triangle.
double spherical_triangle_solid_angle(Vec3 from, Vec3 a, Vec3 b, Vec3 c);

// A direction from `from` towards the triangle, uniformly distributed over
// its solid angle `solid_angle` (which the caller computed with the function
// above; its density is 1 / solid_angle). False where the triangle is
// degenerate as seen from `from` (solid angle 0, collinear directions).
bool sample_spherical_triangle(Vec3 from, Vec3 a, Vec3 b, Vec3 c, double solid_angle, Vec2 u,
                               Vec3* dir);

}  // namespace dofarm::render
