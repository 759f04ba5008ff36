#include "worker/render/scene_motion.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "common/error.h"

namespace dofarm::render {

Affine Affine::trs(Vec3 translation, Quat r, Vec3 scale) {
  // The rotation's matrix (columns: the rotated axes), then scaled per column.
  const Vec3 cols[3] = {r.rotate(Vec3(1, 0, 0)) * scale.x, r.rotate(Vec3(0, 1, 0)) * scale.y,
                        r.rotate(Vec3(0, 0, 1)) * scale.z};
  Affine a;
  for (int c = 0; c < 3; ++c) {
    a.l[0][c] = cols[c].x;
    a.l[1][c] = cols[c].y;
    a.l[2][c] = cols[c].z;
  }
  a.t = translation;
  return a;
}

Affine Affine::operator*(const Affine& o) const {
  Affine a;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      a.l[r][c] = l[r][0] * o.l[0][c] + l[r][1] * o.l[1][c] + l[r][2] * o.l[2][c];
  a.t = point(o.t);
  return a;
}

float Affine::determinant() const {
  return l[0][0] * (l[1][1] * l[2][2] - l[1][2] * l[2][1]) -
         l[0][1] * (l[1][0] * l[2][2] - l[1][2] * l[2][0]) +
         l[0][2] * (l[1][0] * l[2][1] - l[1][1] * l[2][0]);
}

Vec3 Affine::normal(Vec3 n) const {
  // Cofactor matrix C (C = det * L^-T where L is invertible), applied to n.
  const float c[3][3] = {
      {l[1][1] * l[2][2] - l[1][2] * l[2][1], l[1][2] * l[2][0] - l[1][0] * l[2][2],
       l[1][0] * l[2][1] - l[1][1] * l[2][0]},
      {l[0][2] * l[2][1] - l[0][1] * l[2][2], l[0][0] * l[2][2] - l[0][2] * l[2][0],
       l[0][1] * l[2][0] - l[0][0] * l[2][1]},
      {l[0][1] * l[1][2] - l[0][2] * l[1][1], l[0][2] * l[1][0] - l[0][0] * l[1][2],
       l[0][0] * l[1][1] - l[0][1] * l[1][0]}};
  const float s = determinant() < 0 ? -1.0f : 1.0f;
  return Vec3(c[0][0] * n.x + c[0][1] * n.y + c[0][2] * n.z,
              c[1][0] * n.x + c[1][1] * n.y + c[1][2] * n.z,
              c[2][0] * n.x + c[2][1] * n.y + c[2][2] * n.z) *
         s;
}

namespace {

Vec3 blend(Vec3 a, Vec3 b, float w) { return lerp(a, b, w); }
Quat blend(Quat a, Quat b, float w) { return slerp(a, b, w); }
Vec3 hermite(Vec3 p0, Vec3 m0, Vec3 p1, Vec3 m1, float h00, float h10, float h01, float h11) {
  return p0 * h00 + m0 * h10 + p1 * h01 + m1 * h11;
}
Quat hermite(Quat p0, Quat m0, Quat p1, Quat m1, float h00, float h10, float h01, float h11) {
  auto c = [&](float Quat::*f) { return p0.*f * h00 + m0.*f * h10 + p1.*f * h01 + m1.*f * h11; };
  Quat q{c(&Quat::w), c(&Quat::x), c(&Quat::y), c(&Quat::z)};
  const float n = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  return n > 0 ? Quat{q.w / n, q.x / n, q.y / n, q.z / n} : p0;
}
std::vector<float> hermite(const std::vector<float>& p0, const std::vector<float>& m0,
                           const std::vector<float>& p1, const std::vector<float>& m1, float h00,
                           float h10, float h01, float h11) {
  std::vector<float> out(p0.size());
  for (size_t k = 0; k < p0.size() && k < m0.size() && k < p1.size() && k < m1.size(); ++k)
    out[k] = p0[k] * h00 + m0[k] * h10 + p1[k] * h01 + m1[k] * h11;
  return out;
}
std::vector<float> blend(const std::vector<float>& a, const std::vector<float>& b, float w) {
  std::vector<float> out(a.size());
  for (size_t k = 0; k < a.size() && k < b.size(); ++k) out[k] = a[k] * (1.0f - w) + b[k] * w;
  return out;
}

// The track's value at `time` (glTF 2.0, 3.11: clamped outside the keys).
template <typename T>
T sample(const Track<T>& track, float time) {
  const auto& ts = track.times;
  if (time <= ts.front()) return track.values.front();
  if (time >= ts.back()) return track.values.back();
  const size_t i =
      size_t(std::upper_bound(ts.begin(), ts.end(), time) - ts.begin());  // ts[i-1] <= time < ts[i]
  if (track.step) return track.values[i - 1];
  const float span = ts[i] - ts[i - 1];
  const float w = span > 0 ? (time - ts[i - 1]) / span : 1.0f;
  if (!track.in_tangents.empty()) {
    // glTF 2.0, Appendix C: the Hermite basis, tangents scaled by the span.
    const float w2 = w * w, w3 = w2 * w;
    return hermite(track.values[i - 1], track.out_tangents[i - 1], track.values[i],
                   track.in_tangents[i], 2 * w3 - 3 * w2 + 1, span * (w3 - 2 * w2 + w),
                   -2 * w3 + 3 * w2, span * (w3 - w2));
  }
  return blend(track.values[i - 1], track.values[i], w);
}

}  // namespace

Affine MotionNode::local(float time) const {
  if (!animated()) return fixed;
  return Affine::trs(translation_keys.empty() ? translation : sample(translation_keys, time),
                     rotation_keys.empty() ? rotation : sample(rotation_keys, time),
                     scale_keys.empty() ? scale : sample(scale_keys, time));
}

Affine SceneMotion::world(uint32_t node, float time) const {
  DOFARM_CHECK_OP(size_t(node), <, nodes.size());
  Affine w = nodes[node].local(time);
  for (int p = nodes[node].parent; p >= 0; p = nodes[size_t(p)].parent)
    w = nodes[size_t(p)].local(time) * w;
  return w;
}

CameraTrackKey SceneCamera::at(float time) const {
  const Affine world = motion->world(node, time);
  const Vec3 right = normalize(cross(up, back), Vec3(1, 0, 0));
  const Vec3 w_back = normalize(world.linear(back));
  const Vec3 w_right = normalize(cross(world.linear(cross(back, right)), w_back));
  const Vec3 w_up = cross(w_back, w_right);
  CameraTrackKey key;
  key.time = time;
  key.position = world.point(position);
  key.rotation = quat_from_axes(w_right, w_up, w_back);
  key.yfov_deg = yfov_deg;
  key.aspect = aspect;
  key.ymag = ymag;
  return key;
}

SceneData pose(const SceneData& rest, float time) {
  DOFARM_CHECK(rest.motion != nullptr);
  const SceneMotion& motion = *rest.motion;
  // Everything as rest has it but the texels, which Scene keeps once for
  // all poses (a Scene's own data holds none, so nothing is copied there).
  SceneData out = rest;
  out.textures = {};

  // A node's world transform, once per node.
  std::vector<Affine> world(motion.nodes.size());
  for (size_t i = 0; i < motion.nodes.size(); ++i) {
    const MotionNode& n = motion.nodes[i];
    world[i] = n.parent >= 0 ? world[size_t(n.parent)] * n.local(time) : n.local(time);
  }

  std::vector<bool> moving(rest.tangents.empty() ? 0 : rest.positions.size(), false);
  // The file's TANGENTs of moving vertices, moved with the surface; set
  // after compute_tangents(), which would overwrite them.
  std::vector<std::pair<size_t, SceneData::Tangent>> given_tangents;
  std::vector<Affine> joint_matrix;
  // The transform of vertex k of a part: its node's, or its joints' blend.
  auto vertex_transform = [&](const MovingPart& part, uint32_t k) -> Affine {
    if (part.skin < 0) return world[part.node];
    const Skin& skin = motion.skins[size_t(part.skin)];
    if (skin.first[k] == skin.first[k + 1]) return world[part.node];  // no joint holds it
    Affine blend;
    for (auto& row : blend.l) row[0] = row[1] = row[2] = 0.0f;
    for (uint32_t i = skin.first[k]; i < skin.first[k + 1]; ++i) {
      const Affine& m = joint_matrix[skin.influences[i].joint];
      const float w = skin.influences[i].weight;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) blend.l[r][c] += w * m.l[r][c];
      blend.t += m.t * w;
    }
    return blend;
  };
  for (const MovingPart& part : motion.parts) {
    if (part.skin >= 0) {
      // glTF's joint matrices: world(joint) * inverse bind.
      const Skin& skin = motion.skins[size_t(part.skin)];
      joint_matrix.resize(skin.joints.size());
      for (size_t j = 0; j < skin.joints.size(); ++j)
        joint_matrix[j] = world[skin.joints[j]] * skin.inverse_bind[j];
    }
    std::vector<float> weights;
    if (part.morph >= 0) weights = sample(motion.morphs[size_t(part.morph)].weights, time);
    for (uint32_t k = 0; k < part.vertex_count; ++k) {
      const size_t v = size_t(part.first_vertex) + k, local = size_t(part.local_first) + k;
      Vec3 p = motion.positions[local], n = motion.normals[local];
      if (part.morph >= 0) {
        const Morph& morph = motion.morphs[size_t(part.morph)];
        for (size_t t = 0; t < morph.positions.size() && t < weights.size(); ++t) {
          p += morph.positions[t][k] * weights[t];
          if (!morph.normals[t].empty()) n += morph.normals[t][k] * weights[t];
        }
      }
      const Affine w = vertex_transform(part, k);
      out.positions[v] = w.point(p);
      out.normals[v] = normalize(w.normal(n), Vec3(0.0f));
      if (!moving.empty()) moving[v] = true;
      if (!moving.empty() && !motion.tangents.empty() && length(motion.tangents[local]) > 0.0f) {
        const Vec3 t = normalize(w.linear(motion.tangents[local]), Vec3(0.0f));
        const Vec3 b = w.linear(motion.bitangents[local]);
        given_tangents.push_back(
            {v, {t, dot(cross(out.normals[v], t), b) < 0.0f ? -1.0f : 1.0f}});
      }
    }
    // A skin's winding follows its joints' (blended) transform at its first vertex.
    const Affine w = part.vertex_count > 0 ? vertex_transform(part, 0) : world[part.node];
    if ((w.determinant() < 0) != part.mirrored)
      for (uint32_t k = 0; k + 2 < part.index_count; k += 3)
        std::swap(out.indices[size_t(part.first_index) + k + 1],
                  out.indices[size_t(part.first_index) + k + 2]);
  }

  if (!rest.tangents.empty() && !motion.parts.empty()) {
    compute_tangents(&out);
    if (out.tangents.size() != rest.tangents.size()) out.tangents = rest.tangents;
    // The vertices that do not move keep theirs (the file's or computed);
    // those the file gives a TANGENT for move with the surface.
    for (size_t v = 0; v < rest.tangents.size(); ++v)
      if (!moving[v]) out.tangents[v] = rest.tangents[v];
    for (const auto& [v, tangent] : given_tangents) out.tangents[v] = tangent;
  }

  for (const MovingLight& ml : motion.lights) {
    const Affine& w = world[ml.node];
    PunctualLight& light = out.lights[ml.light];
    light.position = w.point(ml.position);
    light.direction = normalize(w.linear(ml.direction), Vec3(0, 0, -1));
  }
  return out;
}

}  // namespace dofarm::render
