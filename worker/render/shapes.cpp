#include "worker/render/shapes.h"

#include <cmath>
#include <map>
#include <utility>
#include <vector>

#include "common/error.h"

namespace dofarm::render {

uint32_t add_triangle(SceneData& scene, Vec3 a, Vec3 b, Vec3 c, const Material& m) {
  Vec3 n = normalize(cross(b - a, c - a));
  return scene.add_mesh({a, b, c}, {n, n, n}, {{0, 0}, {1, 0}, {0, 1}}, {0, 1, 2}, m);
}

uint32_t add_quad(SceneData& scene, Vec3 p0, Vec3 p1, Vec3 p2, Vec3 p3, const Material& m) {
  Vec3 n = normalize(cross(p1 - p0, p3 - p0));
  return scene.add_mesh({p0, p1, p2, p3}, {n, n, n, n}, {{0, 0}, {1, 0}, {1, 1}, {0, 1}},
                        {0, 1, 2, 0, 2, 3}, m);
}

uint32_t add_quad(SceneData& scene, Vec3 center, Vec3 u, Vec3 v, const Material& m) {
  return add_quad(scene, center - u - v, center + u - v, center + u + v, center - u + v, m);
}

uint32_t add_box(SceneData& scene, Vec3 lo, Vec3 hi, const Material& m, Facing facing) {
  // Corner i has x from bit 0, y from bit 1, z from bit 2. Each face lists its
  // corners counter-clockwise seen from outside.
  auto corner = [&](int i) {
    return Vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
  };
  static constexpr int kFaces[6][4] = {
      {0, 4, 6, 2},  // -x
      {1, 3, 7, 5},  // +x
      {0, 1, 5, 4},  // -y
      {2, 6, 7, 3},  // +y
      {0, 2, 3, 1},  // -z
      {4, 5, 7, 6},  // +z
  };
  std::vector<Vec3> p, n;
  std::vector<Vec2> uv;
  std::vector<uint32_t> idx;
  for (const auto& face : kFaces) {
    Vec3 c[4];
    for (int k = 0; k < 4; ++k) c[k] = corner(face[k]);
    if (facing == Facing::kInward) std::swap(c[1], c[3]);
    Vec3 normal = normalize(cross(c[1] - c[0], c[3] - c[0]));
    auto base = static_cast<uint32_t>(p.size());
    const Vec2 kUv[4] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    for (int k = 0; k < 4; ++k) {
      p.push_back(c[k]);
      n.push_back(normal);
      uv.push_back(kUv[k]);
    }
    for (uint32_t k : {0u, 1u, 2u, 0u, 2u, 3u}) idx.push_back(base + k);
  }
  return scene.add_mesh(p, n, uv, idx, m);
}

namespace {

Vec2 sphere_uv(Vec3 d) {
  return {0.5f + std::atan2(d.x, d.z) / kTwoPi, std::acos(std::clamp(d.y, -1.0f, 1.0f)) * kInvPi};
}

}  // namespace

uint32_t add_icosphere(SceneData& scene, Vec3 center, float radius, int subdivisions,
                       const Material& m, bool smooth) {
  DOFARM_CHECK_GE(subdivisions, 0);
  DOFARM_CHECK_LE(subdivisions, 8);  // 1.3 M triangles; more is a mistake
  const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
  std::vector<Vec3> dirs = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                            {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                            {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (Vec3& d : dirs) d = normalize(d);
  std::vector<uint32_t> tris = {0, 11, 5,  0, 5,  1, 0, 1, 7, 0, 7,  10, 0, 10, 11, 1, 5, 9, 5, 11,
                                4, 11, 10, 2, 10, 7, 6, 7, 1, 8, 3,  9,  4, 3,  4,  2, 3, 2, 6, 3,
                                6, 8,  3,  8, 9,  4, 9, 5, 2, 4, 11, 6,  2, 10, 8,  6, 7, 9, 8, 1};
  for (int level = 0; level < subdivisions; ++level) {
    // Shared edge midpoints keep the mesh watertight.
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> midpoint;
    auto mid = [&](uint32_t a, uint32_t b) {
      auto key = std::minmax(a, b);
      auto [it, inserted] = midpoint.try_emplace(key, static_cast<uint32_t>(dirs.size()));
      if (inserted) dirs.push_back(normalize(dirs[a] + dirs[b]));
      return it->second;
    };
    std::vector<uint32_t> next;
    next.reserve(tris.size() * 4);
    for (size_t i = 0; i < tris.size(); i += 3) {
      uint32_t a = tris[i], b = tris[i + 1], c = tris[i + 2];
      uint32_t ab = mid(a, b), bc = mid(b, c), ca = mid(c, a);
      next.insert(next.end(), {a, ab, ca, b, bc, ab, c, ca, bc, ab, bc, ca});
    }
    tris = std::move(next);
  }
  std::vector<Vec3> p, n;
  std::vector<Vec2> uv;
  if (smooth) {
    for (Vec3 d : dirs) {
      p.push_back(center + d * radius);
      n.push_back(d);
      uv.push_back(sphere_uv(d));
    }
    return scene.add_mesh(p, n, uv, tris, m);
  }
  // Flat: every triangle gets its own three vertices.
  std::vector<uint32_t> idx;
  for (size_t i = 0; i < tris.size(); i += 3) {
    Vec3 a = dirs[tris[i]], b = dirs[tris[i + 1]], c = dirs[tris[i + 2]];
    Vec3 fn = normalize(cross(b - a, c - a));
    for (Vec3 d : {a, b, c}) {
      idx.push_back(static_cast<uint32_t>(p.size()));
      p.push_back(center + d * radius);
      n.push_back(fn);
      uv.push_back(sphere_uv(d));
    }
  }
  return scene.add_mesh(p, n, uv, idx, m);
}

uint32_t add_disk(SceneData& scene, Vec3 center, Vec3 normal, float radius, int segments,
                  const Material& m) {
  DOFARM_CHECK_GE(segments, 3);
  Frame frame(normalize(normal));
  std::vector<Vec3> p = {center}, n = {frame.n};
  std::vector<Vec2> uv = {{0.5f, 0.5f}};
  std::vector<uint32_t> idx;
  for (int i = 0; i < segments; ++i) {
    float phi = kTwoPi * static_cast<float>(i) / static_cast<float>(segments);
    float c = std::cos(phi), s = std::sin(phi);
    p.push_back(center + frame.to_world(Vec3(c, s, 0)) * radius);
    n.push_back(frame.n);
    uv.push_back({0.5f + 0.5f * c, 0.5f - 0.5f * s});
    auto next = static_cast<uint32_t>(1 + (i + 1) % segments);
    // Frame's t, b, n is right-handed, so (centre, t, b) is counter-clockwise
    // seen from +n.
    idx.insert(idx.end(), {0, static_cast<uint32_t>(1 + i), next});
  }
  return scene.add_mesh(p, n, uv, idx, m);
}

}  // namespace dofarm::render
