// Meshes and lights that the scene file animates (glTF node animation): the
// node hierarchy above them with each node's keyframes, the moving parts'
// vertices in their nodes' own space, and pose(), which places them at a
// time. A frame of such a scene is rendered from SceneData posed at the
// frame's time (Scene::at_time), so every buffer, light and BVH of that
// frame sees the scene as it is then.
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "common/math.h"
#include "worker/render/scene_data.h"

namespace dofarm::render {

// An affine map y = L x + t (row-major L).
struct Affine {
  float l[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  Vec3 t{0.0f};
  // glTF's node transform T * R * S (glTF 2.0, 3.5.3).
  static Affine trs(Vec3 translation, Quat rotation, Vec3 scale);
  Affine operator*(const Affine& o) const;  // this after o
  Vec3 point(Vec3 p) const { return linear(p) + t; }
  Vec3 linear(Vec3 v) const {
    return {l[0][0] * v.x + l[0][1] * v.y + l[0][2] * v.z,
            l[1][0] * v.x + l[1][1] * v.y + l[1][2] * v.z,
            l[2][0] * v.x + l[2][1] * v.y + l[2][2] * v.z};
  }
  float determinant() const;
  // A normal's direction after the map: the inverse transpose of L, taken as
  // the cofactor matrix times sign(det), which stays defined (and gives a
  // zero vector, "use the geometric normal") where L is singular, e.g. a
  // node scaled to 0. Not unit.
  Vec3 normal(Vec3 n) const;
};

// Keyframes of one property of a node, in seconds, as glTF's samplers give
// them: linear (vectors) or spherical linear (quaternions) between keys,
// constant until the next key (STEP), or a cubic Hermite spline through the
// keys with their tangents (CUBICSPLINE, glTF 2.0 Appendix C; quaternions
// made unit after it); clamped before the first and after the last key.
template <typename T>
struct Track {
  std::vector<float> times;  // ascending
  std::vector<T> values;
  bool step = false;
  // CUBICSPLINE: each key's in- and out-tangent (per second); empty otherwise.
  std::vector<T> in_tangents, out_tangents;
  bool empty() const { return times.empty(); }
};

struct MotionNode {
  int parent = -1;  // index into SceneMotion::nodes (parents come first); -1: the root's
  // The node's own transform where no track moves it: its matrix for a node
  // without tracks, else its rest translation, rotation and scale, which
  // stand in for a property that has no track (glTF 3.11).
  Affine fixed;
  Vec3 translation{0.0f}, scale{1.0f};
  Quat rotation;
  Track<Vec3> translation_keys, scale_keys;
  Track<Quat> rotation_keys;
  bool animated() const {
    return !translation_keys.empty() || !rotation_keys.empty() || !scale_keys.empty();
  }
  Affine local(float time) const;
};

// A node's meshes: the vertices [first_vertex, first_vertex + vertex_count)
// and indices [first_index, first_index + index_count) of SceneData, which
// the node's world transform places. `local_first` indexes
// SceneMotion::positions and the other per-vertex arrays. `mirrored`: the
// loader swapped the winding of its triangles for the rest pose (a
// transform with a negative determinant, glTF 3.7.4); a pose whose sign
// differs swaps them back.
struct MovingPart {
  uint32_t node = 0;
  uint32_t first_vertex = 0, vertex_count = 0, first_index = 0, index_count = 0;
  uint32_t local_first = 0;
  bool mirrored = false;
  int skin = -1;  // index into SceneMotion::skins: the joints place the vertices, not `node`
  int morph = -1;  // index into SceneMotion::morphs: animated morph targets (before the skin)
};

// Morph targets whose weights are animated (glTF 2.0, 3.7.2.2, 3.11;
// Blender's shape keys): vertex v of the part, in its node's space, is
// base_v + sum_k w_k(t) delta_k,v, and its normal likewise (then made
// unit). Targets with static weights are applied at load.
struct Morph {
  // Per target, per vertex of the part: the position and normal offsets
  // (normal offsets empty where the target has none).
  std::vector<std::vector<Vec3>> positions, normals;
  Track<std::vector<float>> weights;  // one weight per target per key
};

// A skinned mesh's joints (glTF 2.0, 3.7.3): vertex v of the part lands at
// sum_k w_k (world(joint_k) * inverse_bind_k) v, linear blend skinning; its
// node's own transform does not count. Influences per vertex of the part:
// [first[v], first[v + 1]) in `influences` (joint index into `joints`,
// weight), the weights made to sum to 1 at load.
struct Skin {
  std::vector<uint32_t> joints;  // SceneMotion::nodes indices
  std::vector<Affine> inverse_bind;
  std::vector<uint32_t> first;  // vertex_count + 1
  struct Influence {
    uint32_t joint = 0;
    float weight = 0;
  };
  std::vector<Influence> influences;
};

// A KHR_lights_punctual light on a moving node: its position and direction
// in the node's space.
struct MovingLight {
  uint32_t light = 0;  // index into SceneData::lights
  uint32_t node = 0;
  Vec3 position{0.0f}, direction{0, 0, -1};
};

struct SceneMotion {
  std::vector<MotionNode> nodes;
  std::vector<MovingPart> parts;
  std::vector<Skin> skins;
  std::vector<Morph> morphs;
  std::vector<MovingLight> lights;
  // The moving parts' vertices in their nodes' space: positions, normals
  // (zero = none), and where the file gives TANGENT its tangent and
  // bitangent (zero where it gives none; empty when no moving mesh has any).
  std::vector<Vec3> positions, normals, tangents, bitangents;
  // The node's transform to world space at `time` seconds.
  Affine world(uint32_t node, float time) const;
};

// The scene file's camera on its node (glTF 2.0, 3.10.1: at the node's
// origin looking down its -z, +y up): at() gives its pose at any time from
// the node hierarchy's own samplers, exactly, so a frame between two keys
// sees the camera where a spline or a moving parent puts it then.
struct SceneCamera {
  std::shared_ptr<const SceneMotion> motion;  // holds the camera's node and its parents
  uint32_t node = 0;
  // The camera's own frame in its node's space (glTF: the origin, +z back,
  // +y up; other formats: assimp's position, look-at and up).
  Vec3 position{0.0f}, back{0, 0, 1}, up{0, 1, 0};
  float yfov_deg = 40;
  float aspect = 0;  // CameraTrackKey::aspect
  float ymag = 0;    // CameraTrackKey::ymag: > 0 orthographic
  // Clipping planes (glTF znear, zfar; camera.h CameraClip): 0 and
  // infinity where the file gives none.
  float znear = 0.0f, zfar = std::numeric_limits<float>::infinity();
  std::string name;
  // Position and rotation at `time` seconds, the node's world transform
  // orthonormalised (scale in the hierarchy does not leak into the rotation).
  CameraTrackKey at(float time) const;
};

// `rest` with its moving parts and lights placed at `time` seconds (rest
// must have a motion): positions, normals, tangents (the file's, moved with
// the surface, or computed again as compute_tangents() does), the winding
// where a transform mirrors, and the punctual lights. Everything else is
// rest's, except the textures, which are left out: Scene keeps them once
// for all poses (and its own data holds none, so posing copies no texels).
SceneData pose(const SceneData& rest, float time);

}  // namespace dofarm::render
