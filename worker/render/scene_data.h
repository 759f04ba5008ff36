// A scene as plain data, in world space, before Embree sees it: triangles,
// materials, textures and (optionally) a camera animation. Loaded from glTF
// 2.0 / OBJ / FBX by load_scene_data() through assimp, or built in code by the
// shape helpers (tests, analytic scenes).
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "common/math.h"

namespace dofarm::render {

// Linear RGB texture; 8-bit colour data is converted from sRGB on load.
struct Texture {
  int width = 0, height = 0;
  std::vector<float> rgb;  // interleaved, row 0 = top (v = 0 in glTF)
  std::string name;
  // Bilinear, repeat wrapping; uv in glTF convention.
  Vec3 lookup(Vec2 uv) const;
};

// glTF metallic-roughness material (what a glTF material maps onto exactly).
struct Material {
  std::string name;
  Vec3 base_color{0.8f};
  float metallic = 0.0f;
  float roughness = 0.5f;
  Vec3 emission{0.0f};  // radiance emitted (already times emissive strength)
  float ior = 1.5f;
  int base_color_tex = -1;   // index into SceneData::textures; multiplies base_color
  int metal_rough_tex = -1;  // glTF: G = roughness, B = metallic; multiplies the factors
  int emission_tex = -1;     // multiplies emission
  bool is_emissive() const { return emission.x > 0 || emission.y > 0 || emission.z > 0; }
  bool has_textures() const {
    return base_color_tex >= 0 || metal_rough_tex >= 0 || emission_tex >= 0;
  }
};

// Camera animation stored in the scene file (glTF node animation + camera).
struct CameraTrackKey {
  float time = 0;  // seconds
  Vec3 position;
  Quat rotation;  // camera looks down its -z
  float yfov_deg = 40;
  // Width over height of the camera's film as the file gives it (glTF
  // camera.perspective.aspectRatio); 0 when the file does not say.
  float aspect = 0;
};

struct SceneData {
  std::filesystem::path source;  // file it came from (empty if built in code)
  std::vector<Vec3> positions;
  // Per vertex; empty = use geometric normals. Unit length, except that a
  // zero normal means "use the geometric normal" for that vertex (add_mesh
  // writes zeros when meshes with and without normals are mixed).
  std::vector<Vec3> normals;
  std::vector<Vec2> uvs;               // per vertex; empty = no texture coordinates
  std::vector<uint32_t> indices;       // 3 per triangle
  std::vector<uint32_t> tri_material;  // one per triangle
  std::vector<Material> materials;
  std::vector<Texture> textures;
  std::vector<CameraTrackKey> camera_track;  // empty = no camera in the file

  size_t triangle_count() const { return tri_material.size(); }
  // Appends a mesh with its own material; returns the material index. `n` and
  // `uv` are empty or one per vertex of `p`; indices refer to `p`.
  uint32_t add_mesh(const std::vector<Vec3>& p, const std::vector<Vec3>& n,
                    const std::vector<Vec2>& uv, const std::vector<uint32_t>& idx,
                    const Material& m);
};

// Loads a glTF 2.0 (.gltf/.glb), OBJ or FBX file, flattening the node
// hierarchy into world space. Throws SpecError (file name, reason) when the
// file is missing, unreadable, has no triangles, has a non-finite vertex or
// a texture that cannot be loaded. Points and lines are ignored; degenerate
// triangles are kept. HDR emission in glTF comes from
// KHR_materials_emissive_strength, read from the file's JSON because assimp
// 5.2 does not import it.
SceneData load_scene_data(const std::filesystem::path& path);

}  // namespace dofarm::render
