// The glTF / OBJ / FBX loader behind load_scene_data() (scene_data.h),
// shared by its two source files: scene_data.cpp (materials, textures,
// meshes) and scene_loader_nodes.cpp (the node hierarchy: camera track,
// node animation, punctual lights). Not an interface of its own.
#pragma once

#include <assimp/scene.h>

#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "common/error.h"
#include "common/exr_io.h"
#include "common/math.h"
#include "worker/render/gltf_info.h"
#include "worker/render/scene_data.h"
#include "worker/render/scene_motion.h"

namespace dofarm::render::detail {

[[noreturn]] inline void fail(const std::filesystem::path& path, const std::string& why) {
  throw SpecError(FileLoc{path.string()}, "scene", why);
}

bool is_gltf(const std::filesystem::path& path);

inline Vec3 to_vec3(const aiVector3D& v) { return {v.x, v.y, v.z}; }
inline Vec3 to_vec3(const aiColor4D& c) { return {c.r, c.g, c.b}; }
inline Affine to_affine(const aiMatrix4x4& m) {
  Affine a;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) a.l[r][c] = m[r][c];
  a.t = Vec3(m.a4, m.b4, m.c4);
  return a;
}

class Loader {
 public:
  Loader(const std::filesystem::path& path, const aiScene* scene, const GltfInfo& gltf,
         SceneData* out)
      : path_(path), scene_(scene), gltf_(gltf), out_(out) {}

  // Reads every material (and the textures they use) into out->materials.
  void materials();
  // Whether Blender wrote this Collada or FBX file (the generator assimp
  // reports: FBX's Creator, Collada's authoring_tool); false for glTF.
  bool from_blender() const;
  // The scene file's bytes, read once, for what assimp does not pass on of
  // Collada and FBX files (foreign_cameras.h).
  const std::string& file_bytes();

  // Flattens the hierarchy below `node` into world space at the nodes' own
  // transforms; the meshes of nodes that the animation moves (or whose
  // parents it moves) are also kept in their nodes' space
  // (SceneData::motion).
  void node(const aiNode* node, const aiMatrix4x4& parent);

  // The pose of the camera named `name` (empty: the first camera) at every
  // key time on its chain of nodes (SceneData::camera_track); none without
  // a camera or without one of that name. Lists every camera's name in
  // SceneData::camera_names.
  void camera_track(const std::string& name);
  // The KHR_lights_punctual lights (glTF only), placed by their nodes' own
  // transforms; a light on a moving node is kept in SceneMotion as well.
  void lights();
  // The node animation of every node: the channel of the first animation
  // that has one for it (each of Blender's actions is an animation of its
  // own; together they are the timeline). Call before node() and lights().
  void animation_channels();
  // Hands the motion of the moving meshes and lights to the SceneData
  // (none when nothing but the camera moves); warns about animation that
  // is not followed.
  void finish_motion();
  // The file's TANGENTs, per vertex (a zero t where it gives none): they
  // replace the computed ones (glTF 3.7.2.1: MikkTSpace is only the
  // fallback when the file has none).
  const std::vector<SceneData::Tangent>& given_tangents() const { return given_tangents_; }

 private:
  // `with_alpha`: also the image's alpha channel (Texture::alpha). `slot`:
  // the index within the type (assimp files clearcoatRoughnessTexture as
  // CLEARCOAT, 1).
  int texture(const aiMaterial* am, std::initializer_list<aiTextureType> types, bool srgb,
              bool with_alpha = false, unsigned slot = 0);
  // A texture assimp 5.2 does not hand out, from the file's JSON
  // (GltfTextureRef); -1 where the info names none.
  // A reference to a texture the file does not have is named in a warning
  // (`which` material, `key`).
  int gltf_texture(const GltfTextureInfo& info, bool srgb, bool with_alpha,
                   const std::string& which, const char* key);
  // The texture `name` (a file beside the scene, assimp's "*k" for an
  // embedded image, or, with `held_image` >= 0, that image of the file read
  // by read_gltf_image()) read through `sampler`, loaded once per (name,
  // srgb, sampler); with its alpha channel when `with_alpha`.
  int load_texture(const std::string& name, const TextureSampler& sampler, bool srgb,
                   bool with_alpha, int held_image = -1);
  static RgbImage decode_embedded(const aiTexture* t, const std::string& name, bool srgb);
  // `motion_node` >= 0: the node moves; its vertices are also kept in its space.
  void mesh(const aiMesh* m, const aiMatrix4x4& world, const char* node_name, int motion_node);
  // The skin of `m` (its bones: joints, inverse bind matrices, weights) as
  // a SceneMotion::skins entry; returns its index.
  int skin(const aiMesh* m, const char* node_name);
  // The morph-weight animation of node `node_name` (the first animation
  // with one; assimp names it after the node), with its ticks per second
  // and the index of its animation; null where none.
  const aiMeshMorphAnim* morph_channel(const char* node_name, double* ticks_per_second,
                                       unsigned* animation) const;
  // The glTF sampler behind that animation's `weights` channel of the node
  // (its interpolation and, for CUBICSPLINE, its output), or null.
  const GltfInfo::AnimatedPath* weights_path(const char* node_name, unsigned animation) const;
  // Whether the animation moves `n` or one of its parents.
  bool moves(const aiNode* n) const {
    for (; n; n = n->mParent)
      if (channels_.count(n->mName.C_Str())) return true;
    return false;
  }
  // `n`'s index in motion_->nodes, adding it and its parents on first use.
  uint32_t motion_node(const aiNode* n);
  // The channel whose keys animate `path` ("translation", "rotation",
  // "scale") of node `name`, or null: in a glTF file the first animation
  // whose JSON targets that path (assimp fills a channel's other paths with
  // the node's static value, so a later animation's real keys would be
  // hidden); else (other formats, unnamed nodes) the first animation with a
  // channel for the node. Sets its ticks per second, `step` for a STEP
  // sampler, and `cubic` to a CUBICSPLINE sampler's output as the JSON
  // gives it (GltfInfo::AnimatedPath::cubic), else null.
  const aiNodeAnim* path_channel(const std::string& name, const char* path,
                                 double* ticks_per_second, bool* step,
                                 const std::vector<float>** cubic) const;
  // Refuses a material with a non-finite value or an emission above
  // kMaxRadiance (its brightest emission texel counted).
  void check_material(const Material& m, unsigned index) const;
  const GltfMaterialInfo* gltf_material(unsigned i, const std::string& name) const {
    if (i < gltf_.materials.size() && gltf_.materials[i].name == name) return &gltf_.materials[i];
    return nullptr;
  }

  const std::filesystem::path& path_;
  const aiScene* scene_;
  const GltfInfo& gltf_;
  SceneData* out_;
  // Shared textures load once per (image, colour space, sampler).
  std::map<std::tuple<std::string, bool, TextureSampler>, int> texture_index_;
  std::set<int> alpha_loaded_;  // textures whose alpha channel was asked for
  // Per vertex, where the file gives tangents (a zero t elsewhere).
  std::vector<SceneData::Tangent> given_tangents_;
  struct Channel {
    const aiNodeAnim* keys;
    double ticks_per_second;
  };
  std::map<std::string, Channel> channels_;  // by node name
  std::shared_ptr<SceneMotion> motion_ = std::make_shared<SceneMotion>();
  std::map<const aiNode*, uint32_t> motion_index_;
  // Collada: the geometries instantiated without a material binding, which
  // assimp 5.2 gives the file's first material, and the grey diffuse
  // material they get instead (materials()).
  std::set<std::string> unbound_geometries_;
  uint32_t unbound_material_ = 0;
  std::optional<std::string> file_bytes_;  // file_bytes()
};

}  // namespace dofarm::render::detail
