#include "worker/render/scene_data.h"

#include <assimp/DefaultIOSystem.h>
#include <assimp/GltfMaterial.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <assimp/Importer.hpp>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <tuple>

#include "common/content_hash.h"
#include "common/error.h"
#include "common/exr_io.h"
#include "worker/render/gltf_info.h"
#include "worker/render/scene_motion.h"

namespace dofarm::render {

// ---------------------------------------------------------------------------
// Spot falloff

float spot_falloff(float cos_angle, float cos_inner, float cos_outer) {
  // KHR_lights_punctual, "Inner and Outer Cone Angles" (the recommended
  // implementation): linear in the cosine between the cones, then squared.
  const float scale = 1.0f / std::max(1e-3f, cos_inner - cos_outer);
  const float t = std::clamp((cos_angle - cos_outer) * scale, 0.0f, 1.0f);
  return t * t;
}

// ---------------------------------------------------------------------------
// SceneData

uint32_t SceneData::add_mesh(const std::vector<Vec3>& p, const std::vector<Vec3>& n,
                             const std::vector<Vec2>& uv, const std::vector<uint32_t>& idx,
                             const Material& m) {
  DOFARM_CHECK(n.empty() || n.size() == p.size());
  DOFARM_CHECK(uv.empty() || uv.size() == p.size());
  DOFARM_CHECK_EQ(idx.size() % 3, size_t{0});
  for (uint32_t i : idx) DOFARM_CHECK_LT(i, p.size());
  const size_t base = positions.size();
  // Keep the per-vertex arrays either empty or as long as `positions`. A zero
  // normal stands for "use the geometric normal" and a zero uv is harmless.
  const bool keep_normals = !normals.empty() || !n.empty();
  const bool keep_uvs = !uvs.empty() || !uv.empty();
  positions.insert(positions.end(), p.begin(), p.end());
  if (keep_normals) {
    normals.resize(base, Vec3(0.0f));
    if (n.empty()) {
      normals.resize(positions.size(), Vec3(0.0f));
    } else {
      normals.insert(normals.end(), n.begin(), n.end());
    }
  }
  if (keep_uvs) {
    uvs.resize(base, Vec2(0, 0));
    if (uv.empty()) {
      uvs.resize(positions.size(), Vec2(0, 0));
    } else {
      uvs.insert(uvs.end(), uv.begin(), uv.end());
    }
  }
  if (!uvs1.empty()) {
    uvs1.resize(base, Vec2(0, 0));
    if (uvs.size() == positions.size())
      uvs1.insert(uvs1.end(), uvs.begin() + ptrdiff_t(base), uvs.end());
    uvs1.resize(positions.size(), Vec2(0, 0));
  }
  for (uint32_t i : idx) indices.push_back(static_cast<uint32_t>(base + i));
  const auto material = static_cast<uint32_t>(materials.size());
  materials.push_back(m);
  tri_material.insert(tri_material.end(), idx.size() / 3, material);
  return material;
}

// ---------------------------------------------------------------------------
// Loading

namespace {

[[noreturn]] void fail(const std::filesystem::path& path, const std::string& why) {
  throw SpecError(FileLoc{path.string()}, "scene", why);
}

bool is_gltf(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext == ".gltf" || ext == ".glb";
}

Vec3 to_vec3(const aiVector3D& v) { return {v.x, v.y, v.z}; }
Vec3 to_vec3(const aiColor4D& c) { return {c.r, c.g, c.b}; }

class Loader {
 public:
  Loader(const std::filesystem::path& path, const aiScene* scene, const GltfInfo& gltf,
         SceneData* out)
      : path_(path), scene_(scene), gltf_(gltf), out_(out) {}

  void materials() {
    for (unsigned i = 0; i < scene_->mNumMaterials; ++i) {
      const aiMaterial* am = scene_->mMaterials[i];
      Material m;
      m.name = am->GetName().C_Str();
      aiColor4D color;
      if (am->Get(AI_MATKEY_BASE_COLOR, color) == AI_SUCCESS ||
          am->Get(AI_MATKEY_COLOR_DIFFUSE, color) == AI_SUCCESS) {
        m.base_color = to_vec3(color);
      }
      float value = 0;
      m.metallic = am->Get(AI_MATKEY_METALLIC_FACTOR, value) == AI_SUCCESS ? value : 0.0f;
      if (am->Get(AI_MATKEY_ROUGHNESS_FACTOR, value) == AI_SUCCESS) {
        m.roughness = value;
      } else if (am->Get(AI_MATKEY_SHININESS, value) == AI_SUCCESS && value >= 0) {
        // Phong exponent -> Beckmann/GGX roughness via alpha = sqrt(2 / (Ns + 2))
        // (Walter et al. 2007, eq. 33), then roughness = sqrt(alpha) since
        // glTF's alpha is roughness^2.
        m.roughness = std::sqrt(std::sqrt(2.0f / (value + 2.0f)));
      }
      if (am->Get(AI_MATKEY_COLOR_EMISSIVE, color) == AI_SUCCESS) {
        float strength = 1.0f;
        if (am->Get(AI_MATKEY_EMISSIVE_INTENSITY, value) == AI_SUCCESS) {
          strength = value;  // a newer assimp imports the extension itself
        } else if (const GltfMaterialInfo* g = gltf_material(i, m.name)) {
          strength = g->emissive_strength;
        }
        m.emission = to_vec3(color) * strength;
      }
      // What the loader reads of the glTF beyond assimp; null for other formats.
      const GltfMaterialInfo* g = gltf_material(i, m.name);
      if (g && g->ior_present) {
        // glTF: KHR_materials_ior as written. IOR 1 is a valid value (an
        // interface that reflects nothing: F0 = 0, the base layer alone,
        // docs/renderer.md); the schema's minimum is 1.
        if (std::isfinite(g->ior) && g->ior >= 1.0 && g->ior <= 1e4) {
          m.ior = float(g->ior);
        } else {
          spdlog::warn("{}: material \"{}\": KHR_materials_ior ior {} is outside [1, 1e4]; "
                       "using the default 1.5",
                       path_.string(), m.name, g->ior);
        }
      } else if (!g && am->Get(AI_MATKEY_REFRACTI, value) == AI_SUCCESS && value > 1.0f &&
                 std::isfinite(value)) {
        // Other formats (OBJ's Ni, FBX): their exporters write 1 (or 0) for
        // "not set", so only a value above 1 counts there.
        m.ior = value;
      }
      if (g) apply_material_extensions(path_, *g, i, &m);
      if (g && (g->mask || g->blend)) {
        m.alpha_mask = true;
        m.alpha_blend = g->blend;
        m.alpha_cutoff = g->mask && std::isfinite(g->alpha_cutoff) ? g->alpha_cutoff : 0.5f;
        m.base_alpha = std::isfinite(g->base_alpha) ? g->base_alpha : 1.0f;
      }
      m.base_color_tex = texture(am, {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE}, true,
                                 /*with_alpha=*/m.alpha_mask);
      // glTF metallicRoughnessTexture: assimp 5.2 files it under UNKNOWN
      // (AI_MATKEY_GLTF_PBRMETALLICROUGHNESS_METALLICROUGHNESS_TEXTURE).
      m.metal_rough_tex = texture(am, {aiTextureType_UNKNOWN}, false);
      m.emission_tex = texture(am, {aiTextureType_EMISSIVE}, true);
      if (g) {
        // glTF normalTexture (assimp files it under NORMALS): linear values.
        // Other formats' bump and normal maps are not read.
        m.normal_tex = texture(am, {aiTextureType_NORMALS}, false);
        // The extensions' textures, linear (glTF: R transmission, R clearcoat,
        // G clearcoat roughness), only where the file names them.
        if (g->transmission_tex.present)
          m.transmission_tex = texture(am, {aiTextureType_TRANSMISSION}, false);
        if (g->clearcoat_tex.present)
          m.clearcoat_tex = texture(am, {aiTextureType_CLEARCOAT}, false, false, 0);
        if (g->clearcoat_rough_tex.present)
          m.clearcoat_rough_tex = texture(am, {aiTextureType_CLEARCOAT}, false, false, 1);
        // clearcoatNormalTexture (assimp: CLEARCOAT, 2), linear like normalTexture.
        // KHR_materials_specular's, which assimp 5.2 does not read: A
        // multiplies specularFactor, RGB (sRGB) specularColorFactor.
        const std::string which = "material " + std::to_string(i) + " (\"" + m.name + "\")";
        m.specular_tex =
            gltf_texture(g->specular_tex, false, /*with_alpha=*/true, which, "specularTexture");
        m.specular_color_tex =
            gltf_texture(g->specular_color_tex, true, false, which, "specularColorTexture");
        if (g->clearcoat_normal_tex.present) {
          m.clearcoat_normal_tex = texture(am, {aiTextureType_CLEARCOAT}, false, false, 2);
          m.clearcoat_normal_scale =
              std::isfinite(g->clearcoat_normal_scale) ? g->clearcoat_normal_scale : 1.0f;
        }
        // KHR_materials_sheen: colour (sRGB) in slot 0, roughness in the
        // alpha of slot 1 (often the same image).
        if (g->sheen_color_tex.present)
          m.sheen_color_tex = texture(am, {aiTextureType_SHEEN}, true, false, 0);
        if (g->sheen_rough_tex.present)
          m.sheen_rough_tex = texture(am, {aiTextureType_SHEEN}, true, /*with_alpha=*/true, 1);
        m.normal_scale = std::isfinite(g->normal_scale) ? g->normal_scale : 1.0f;
        // Each slot's transform and texture coordinate set (0 or 1; a
        // higher set is named in a warning and TEXCOORD_0 read instead).
        const std::tuple<const char*, const GltfTextureInfo*, UvTransform*> slots[] = {
            {"baseColorTexture", &g->base_color, &m.base_color_uv},
            {"metallicRoughnessTexture", &g->metal_rough, &m.metal_rough_uv},
            {"emissiveTexture", &g->emission, &m.emission_uv},
            {"normalTexture", &g->normal, &m.normal_uv},
            {"transmissionTexture", &g->transmission_tex, &m.transmission_uv},
            {"clearcoatTexture", &g->clearcoat_tex, &m.clearcoat_uv},
            {"clearcoatRoughnessTexture", &g->clearcoat_rough_tex, &m.clearcoat_rough_uv},
            {"sheenColorTexture", &g->sheen_color_tex, &m.sheen_color_uv},
            {"sheenRoughnessTexture", &g->sheen_rough_tex, &m.sheen_rough_uv},
            {"clearcoatNormalTexture", &g->clearcoat_normal_tex, &m.clearcoat_normal_uv},
            {"specularTexture", &g->specular_tex, &m.specular_uv},
            {"specularColorTexture", &g->specular_color_tex, &m.specular_color_uv}};
        for (const auto& [slot, tex, uv] : slots) {
          *uv = tex->transform;
          if (tex->tex_coord == 1) {
            uv->set = 1;
          } else if (tex->tex_coord != 0) {
            spdlog::warn(
                "{}: material {} (\"{}\"): {} reads TEXCOORD_{}; dofarm reads TEXCOORD_0 "
                "and TEXCOORD_1 only and uses TEXCOORD_0",
                path_.string(), i, m.name, slot, tex->tex_coord);
          }
        }
      }
      check_material(m, i);
      out_->materials.push_back(std::move(m));
    }
  }

  // Flattens the hierarchy below `node` into world space at the nodes' own
  // transforms; the meshes of nodes that the animation moves (or whose
  // parents it moves) are also kept in their nodes' space
  // (SceneData::motion).
  void node(const aiNode* node, const aiMatrix4x4& parent) {
    const aiMatrix4x4 world = parent * node->mTransformation;
    const int moving = node->mNumMeshes > 0 && moves(node) ? int(motion_node(node)) : -1;
    for (unsigned k = 0; k < node->mNumMeshes; ++k) {
      mesh(scene_->mMeshes[node->mMeshes[k]], world, node->mName.C_Str(), moving);
    }
    for (unsigned c = 0; c < node->mNumChildren; ++c) this->node(node->mChildren[c], world);
  }

  void camera_track();
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
  // channel for the node. Sets its ticks per second, and `step` for a STEP
  // sampler; a CUBICSPLINE one is named in a warning.
  const aiNodeAnim* path_channel(const std::string& name, const char* path,
                                 double* ticks_per_second, bool* step) const;
  void check_material(const Material& m, unsigned index) const {
    const std::string which = "material " + std::to_string(index) + " (\"" + m.name + "\")";
    bool ok = is_finite(m.base_color) && is_finite(m.emission) && std::isfinite(m.metallic) &&
              std::isfinite(m.roughness);
    if (!ok) fail(path_, which + " has a non-finite value");
    // An emission texture multiplies the factor: its brightest texel counts
    // (an 8-bit one is at most 1; an HDR one loaded for an OBJ may be more).
    float peak = max_component(m.emission);
    if (m.emission_tex >= 0 && peak > 0) {
      float texel = 0;
      for (float v : out_->textures[m.emission_tex].rgb) texel = std::max(texel, v);
      peak *= texel;
    }
    if (!(peak <= kMaxRadiance))
      fail(path_, which + " emits radiance " + fmt::format("{:g}", peak) +
                      ", above the bound kMaxRadiance = 1e12");
  }
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
};

int Loader::texture(const aiMaterial* am, std::initializer_list<aiTextureType> types, bool srgb,
                    bool with_alpha, unsigned slot) {
  for (aiTextureType type : types) {
    aiString file;
    if (am->GetTexture(type, slot, &file) != AI_SUCCESS) continue;
    std::string name = file.C_Str();
    if (name.empty()) continue;
    // The glTF sampler, as assimp reads it (other formats: repeat, bilinear).
    TextureSampler sampler;
    int filter = 0;
    if (am->Get(AI_MATKEY_GLTF_MAPPINGFILTER_MAG(type, slot), filter) == AI_SUCCESS)
      sampler.nearest = filter == 9728;  // glTF NEAREST
    auto wrap_of = [&](const char* key, unsigned t, unsigned i) {
      int mode = aiTextureMapMode_Wrap;
      if (am->Get(key, t, i, mode) != AI_SUCCESS) return TextureWrap::kRepeat;
      return mode == aiTextureMapMode_Clamp    ? TextureWrap::kClamp
             : mode == aiTextureMapMode_Mirror ? TextureWrap::kMirror
                                               : TextureWrap::kRepeat;
    };
    sampler.wrap_u = wrap_of(AI_MATKEY_MAPPINGMODE_U(type, slot));
    sampler.wrap_v = wrap_of(AI_MATKEY_MAPPINGMODE_V(type, slot));
    return load_texture(name, sampler, srgb, with_alpha);
  }
  return -1;
}

int Loader::gltf_texture(const GltfTextureInfo& info, bool srgb, bool with_alpha,
                         const std::string& which, const char* key) {
  if (!info.present) return -1;
  if (info.index < 0 || size_t(info.index) >= gltf_.textures.size() ||
      gltf_.textures[size_t(info.index)].name.empty()) {
    spdlog::warn(
        "{}: {}: {} names texture {}, which the file does not have (or which has no "
        "image); ignored",
        path_.string(), which, key, info.index);
    return -1;
  }
  const GltfTextureRef& ref = gltf_.textures[size_t(info.index)];
  return load_texture(ref.name, ref.sampler, srgb, with_alpha, ref.held ? ref.image : -1);
}

int Loader::load_texture(const std::string& name, const TextureSampler& sampler, bool srgb,
                         bool with_alpha, int held_image) {
  // Held in the file: assimp's "*<index>" (a .glb buffer view or a data:
  // URI it decoded), or image `held_image` of the glTF read here (one
  // assimp did not load). Their bytes are part of the scene file, which the
  // job snapshot hashes.
  const aiTexture* embedded = held_image < 0 ? scene_->GetEmbeddedTexture(name.c_str()) : nullptr;
  if (!embedded && held_image < 0 && name[0] == '*')
    fail(path_, "texture \"" + name + "\" is not in the file");
  const bool in_file = embedded || held_image >= 0;
  std::filesystem::path tex_path = path_.parent_path() / name;
  auto key = std::make_tuple(in_file ? name : tex_path.lexically_normal().string(), srgb, sampler);
  // Read (and the file's JSON parsed) once, though colour and alpha both need them.
  std::optional<std::string> held;
  auto held_bytes = [&]() -> const std::string& {
    if (!held) held = read_gltf_image(path_, held_image);
    return *held;
  };
  // The alpha channel, once per texture, when a material asks for it.
  auto add_alpha = [&](int index) {
    if (!with_alpha || !alpha_loaded_.insert(index).second) return index;
    Texture& tex = out_->textures[size_t(index)];
    try {
      if (embedded && embedded->mHeight != 0) {  // raw texels
        tex.alpha.resize(size_t(embedded->mWidth) * embedded->mHeight);
        for (size_t k = 0; k < tex.alpha.size(); ++k) tex.alpha[k] = embedded->pcData[k].a / 255.0f;
      } else if (embedded) {
        tex.alpha = decode_image_alpha(embedded->pcData, embedded->mWidth, name);
      } else if (held_image >= 0) {
        const std::string& bytes = held_bytes();
        tex.alpha = decode_image_alpha(bytes.data(), bytes.size(), name);
      } else {
        tex.alpha = load_image_alpha(tex_path);
      }
    } catch (const std::exception& e) {
      fail(path_, std::string("texture: ") + e.what());
    }
    if (!tex.alpha.empty() && tex.alpha.size() != size_t(tex.width) * size_t(tex.height))
      fail(path_, "texture \"" + name + "\": its alpha channel and colour differ in size");
    return index;
  };
  if (auto it = texture_index_.find(key); it != texture_index_.end()) return add_alpha(it->second);
  RgbImage image;
  try {
    if (embedded) {
      image = decode_embedded(embedded, name, srgb);
    } else if (held_image >= 0) {
      const std::string& bytes = held_bytes();
      image = decode_rgb_image(bytes.data(), bytes.size(), name, srgb);
    } else {
      image = load_rgb_image(tex_path, srgb);
    }
  } catch (const std::exception& e) {
    fail(path_, std::string("texture: ") + e.what());
  }
  Texture tex;
  tex.width = image.width;
  tex.height = image.height;
  tex.rgb = std::move(image.rgb);
  tex.name = name;
  tex.sampler = sampler;
  out_->textures.push_back(std::move(tex));
  int index = static_cast<int>(out_->textures.size()) - 1;
  texture_index_.emplace(key, index);
  return add_alpha(index);
}

RgbImage Loader::decode_embedded(const aiTexture* t, const std::string& name, bool srgb) {
  const std::string label =
      name + (t->mFilename.length ? " (" + std::string(t->mFilename.C_Str()) + ")" : "");
  if (t->mHeight == 0)  // compressed: mWidth bytes of a PNG, JPEG, ... file
    return decode_rgb_image(t->pcData, t->mWidth, label, srgb);
  // Raw 8-bit texels (formats other than glTF), converted like a file's.
  RgbImage img;
  img.width = static_cast<int>(t->mWidth);
  img.height = static_cast<int>(t->mHeight);
  img.rgb.resize(size_t(t->mWidth) * t->mHeight * 3);
  for (size_t i = 0; i < size_t(t->mWidth) * t->mHeight; ++i) {
    const uint8_t c[3] = {t->pcData[i].r, t->pcData[i].g, t->pcData[i].b};
    for (int k = 0; k < 3; ++k)
      img.rgb[i * 3 + k] = srgb ? srgb_to_linear(c[k] / 255.0f) : c[k] / 255.0f;
  }
  return img;
}

void Loader::mesh(const aiMesh* m, const aiMatrix4x4& world, const char* node_name,
                  int motion_node) {
  // Normals transform by the inverse transpose, so non-uniform scale keeps
  // them perpendicular to the surface.
  aiMatrix3x3 normal_matrix(world);
  const bool mirrored = normal_matrix.Determinant() < 0;
  normal_matrix.Inverse().Transpose();
  const auto base = static_cast<uint32_t>(out_->positions.size());
  const auto first_index = static_cast<uint32_t>(out_->indices.size());
  const bool has_uv = m->HasTextureCoords(0);
  if (has_uv && out_->uvs.empty()) out_->uvs.assign(base, Vec2(0, 0));
  // TEXCOORD_1 only where the mesh's material reads it. A mesh without the
  // set (glTF requires it then) reads its TEXCOORD_0 in its place.
  const uint32_t material = m->mMaterialIndex;
  const bool wants_uv1 = material < out_->materials.size() && out_->materials[material].reads_uv1();
  const bool has_uv1 = wants_uv1 && m->HasTextureCoords(1);
  if (wants_uv1 && out_->uvs1.empty()) out_->uvs1.assign(base, Vec2(0, 0));
  const bool keep_uv1 = wants_uv1 || !out_->uvs1.empty();
  if (wants_uv1 && !has_uv1)
    spdlog::warn(
        "{}: mesh \"{}\" of node \"{}\" has no TEXCOORD_1, which its material \"{}\" reads; "
        "TEXCOORD_0 used",
        path_.string(), m->mName.C_Str(), node_name, out_->materials[material].name);
  for (unsigned v = 0; v < m->mNumVertices; ++v) {
    Vec3 p = to_vec3(world * m->mVertices[v]);
    if (!is_finite(p)) {
      fail(path_, "mesh \"" + std::string(m->mName.C_Str()) + "\" of node \"" + node_name +
                      "\": vertex " + std::to_string(v) + " is not finite");
    }
    out_->positions.push_back(p);
    // aiProcess_GenSmoothNormals fills in normals where the file has none.
    const Vec3 n = normalize(m->HasNormals() ? to_vec3(normal_matrix * m->mNormals[v]) : Vec3(0.0f),
                             Vec3(0.0f));
    out_->normals.push_back(n);
    // A glTF TANGENT (assimp 5.2: mTangents, and mBitangents = cross(n, t) w
    // with the file's w): the tangent moves with the surface (the world
    // matrix, not the normals' inverse transpose). glTF's bitangent is the
    // map's +y, the image's up, as SceneData::tangents' is, so w carries
    // over (checked against Blender's export: bench/cycles/
    // gltf_features_vs_cycles.sh, the normal map with TANGENT).
    if (m->HasTangentsAndBitangents() && m->HasNormals()) {
      aiMatrix3x3 linear(world);
      const Vec3 t = normalize(to_vec3(linear * m->mTangents[v]), Vec3(0.0f));
      const Vec3 b = to_vec3(linear * m->mBitangents[v]);
      given_tangents_.resize(out_->positions.size());
      given_tangents_.back() = {t, dot(cross(n, t), b) < 0.0f ? -1.0f : 1.0f};
    }
    if (has_uv) {
      out_->uvs.emplace_back(m->mTextureCoords[0][v].x, m->mTextureCoords[0][v].y);
    } else if (!out_->uvs.empty()) {
      out_->uvs.emplace_back(0.0f, 0.0f);
    }
    if (keep_uv1) {
      const unsigned set = has_uv1 ? 1 : 0;
      out_->uvs1.push_back(set || has_uv
                               ? Vec2(m->mTextureCoords[set][v].x, m->mTextureCoords[set][v].y)
                               : Vec2(0.0f, 0.0f));
    }
  }
  for (unsigned f = 0; f < m->mNumFaces; ++f) {
    const aiFace& face = m->mFaces[f];
    if (face.mNumIndices != 3) continue;  // points and lines have no area to render
    // A mirroring transform turns counter-clockwise into clockwise: swap two
    // corners so the front face still agrees with the normals (glTF 3.7.4).
    const unsigned a = face.mIndices[0], b = face.mIndices[mirrored ? 2 : 1],
                   c = face.mIndices[mirrored ? 1 : 2];
    out_->indices.insert(out_->indices.end(), {base + a, base + b, base + c});
    out_->tri_material.push_back(material);
  }
  if (motion_node < 0) return;
  // A moving node's mesh, also in the node's space, for pose().
  SceneMotion& mo = *motion_;
  MovingPart part;
  part.node = uint32_t(motion_node);
  part.first_vertex = base;
  part.vertex_count = m->mNumVertices;
  part.first_index = first_index;
  part.index_count = uint32_t(out_->indices.size()) - first_index;
  part.local_first = uint32_t(mo.positions.size());
  part.mirrored = mirrored;
  const bool tangents = m->HasTangentsAndBitangents() && m->HasNormals();
  if (tangents) {
    mo.tangents.resize(mo.positions.size());
    mo.bitangents.resize(mo.positions.size());
  }
  for (unsigned v = 0; v < m->mNumVertices; ++v) {
    mo.positions.push_back(to_vec3(m->mVertices[v]));
    mo.normals.push_back(m->HasNormals() ? normalize(to_vec3(m->mNormals[v]), Vec3(0.0f))
                                         : Vec3(0.0f));
    if (tangents) {
      mo.tangents.push_back(to_vec3(m->mTangents[v]));
      mo.bitangents.push_back(to_vec3(m->mBitangents[v]));
    }
  }
  mo.parts.push_back(part);
}

// --- camera animation --------------------------------------------------------

void Loader::camera_track() {
  if (scene_->mNumCameras == 0) return;
  // The first camera is the scene's camera; others are ignored.
  const aiCamera* cam = scene_->mCameras[0];
  const aiNode* cam_node = scene_->mRootNode->FindNode(cam->mName);
  if (!cam_node) return;
  // The camera node's world transform at the union of the key times on
  // its chain (root ... camera node), each node's keys as for meshes
  // (SceneMotion); camera_for_frame() interpolates between these keys. A
  // STEP track's value jumps at its keys: the instant before each key is a
  // key of the track as well, so the camera holds still until the jump.
  const uint32_t cam_index = motion_node(cam_node);
  std::set<float> times;
  auto add_times = [&times](const auto& track) {
    for (size_t i = 0; i < track.times.size(); ++i) {
      times.insert(track.times[i]);
      if (track.step && i > 0)
        times.insert(std::nextafter(track.times[i], -std::numeric_limits<float>::infinity()));
    }
  };
  for (int n = int(cam_index); n >= 0; n = motion_->nodes[size_t(n)].parent) {
    const MotionNode& node = motion_->nodes[size_t(n)];
    add_times(node.translation_keys);
    add_times(node.rotation_keys);
    add_times(node.scale_keys);
  }
  if (times.empty()) times.insert(0.0f);  // a static camera: one key

  // A glTF camera sits at its node's origin looking down -z with +y up
  // (glTF 2.0, 3.10.1). assimp 5.2.5 also copies the node's translation into
  // aiCamera::mPosition, which would apply it twice, so for glTF the camera's
  // own frame is taken from the spec rather than from aiCamera.
  const bool gltf = is_gltf(path_);
  const Vec3 cam_position = gltf ? Vec3(0.0f) : to_vec3(cam->mPosition);
  const Vec3 back = gltf ? Vec3(0, 0, 1) : -normalize(to_vec3(cam->mLookAt), Vec3(0, 0, -1));
  const Vec3 up_hint = gltf ? Vec3(0, 1, 0) : normalize(to_vec3(cam->mUp), Vec3(0, 1, 0));
  // assimp's glTF2 importer stores mHorizontalFOV = yfov * aspect (checked
  // against a file with yfov 0.8, aspect 2: it reports 1.6), so dividing
  // recovers glTF's yfov exactly. Other importers store the full horizontal
  // angle, which converts through the tangents.
  const float aspect = cam->mAspect > 0 ? cam->mAspect : 1.0f;
  const float yfov = gltf ? cam->mHorizontalFOV / aspect
                          : 2.0f * std::atan(std::tan(cam->mHorizontalFOV * 0.5f) / aspect);
  const Vec3 right = normalize(cross(up_hint, back), Vec3(1, 0, 0));
  const Vec3 up = cross(back, right);
  for (float t : times) {
    const Affine world = motion_->world(cam_index, t);
    // Orthonormalise: scale in the hierarchy must not leak into the rotation.
    Vec3 w_back = normalize(world.linear(back));
    Vec3 w_right = normalize(cross(world.linear(up), w_back));
    Vec3 w_up = cross(w_back, w_right);
    CameraTrackKey key;
    key.time = t;
    key.position = world.point(cam_position);
    key.rotation = quat_from_axes(w_right, w_up, w_back);
    key.yfov_deg = yfov * 180.0f / kPi;
    key.aspect = cam->mAspect > 0 ? cam->mAspect : 0.0f;
    if (!is_finite(key.position) || !std::isfinite(key.yfov_deg)) {
      fail(path_, "camera \"" + std::string(cam->mName.C_Str()) + "\" has a non-finite transform");
    }
    out_->camera_track.push_back(key);
  }
}

// --- node animation (meshes and lights) ---------------------------------------

void Loader::animation_channels() {
  for (unsigned a = 0; a < scene_->mNumAnimations; ++a) {
    const aiAnimation* anim = scene_->mAnimations[a];
    const double tps = anim->mTicksPerSecond > 0 ? anim->mTicksPerSecond : 1.0;
    for (unsigned c = 0; c < anim->mNumChannels; ++c)
      channels_.emplace(anim->mChannels[c]->mNodeName.C_Str(), Channel{anim->mChannels[c], tps});
  }
}

namespace {

Affine to_affine(const aiMatrix4x4& m) {
  Affine a;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) a.l[r][c] = m[r][c];
  a.t = Vec3(m.a4, m.b4, m.c4);
  return a;
}

// assimp's keys (ticks) as a track in seconds. assimp 5.2 gives every key
// of a glTF sampler as a value (of a CUBICSPLINE sampler: the spline's
// points, without their tangents).
template <typename Key, typename T, typename Convert>
void read_keys(const Key* keys, unsigned count, double ticks_per_second, Track<T>* track,
               Convert convert) {
  for (unsigned i = 0; i < count; ++i) {
    track->times.push_back(float(keys[i].mTime / ticks_per_second));
    track->values.push_back(convert(keys[i].mValue));
  }
}

}  // namespace

uint32_t Loader::motion_node(const aiNode* n) {
  if (auto it = motion_index_.find(n); it != motion_index_.end()) return it->second;
  MotionNode node;
  node.parent = n->mParent ? int(motion_node(n->mParent)) : -1;
  node.fixed = to_affine(n->mTransformation);
  const std::string name = n->mName.C_Str();
  if (auto it = channels_.find(name); it != channels_.end()) {
    // glTF: an animated node has translation, rotation and scale, not a
    // matrix (3.11), so the decomposition is exact.
    aiVector3D s, t;
    aiQuaternion r;
    n->mTransformation.Decompose(s, r, t);
    node.translation = to_vec3(t);
    node.scale = to_vec3(s);
    node.rotation = Quat{r.w, r.x, r.y, r.z};
    auto vec = [](const aiVector3D& v) { return to_vec3(v); };
    double tps = 1;
    bool step = false;
    if (const aiNodeAnim* ch = path_channel(name, "translation", &tps, &step)) {
      read_keys(ch->mPositionKeys, ch->mNumPositionKeys, tps, &node.translation_keys, vec);
      node.translation_keys.step = step;
    }
    if (const aiNodeAnim* ch = path_channel(name, "scale", &tps, &step)) {
      read_keys(ch->mScalingKeys, ch->mNumScalingKeys, tps, &node.scale_keys, vec);
      node.scale_keys.step = step;
    }
    if (const aiNodeAnim* ch = path_channel(name, "rotation", &tps, &step)) {
      read_keys(ch->mRotationKeys, ch->mNumRotationKeys, tps, &node.rotation_keys,
                [](const aiQuaternion& q) {
                  return Quat{q.w, q.x, q.y, q.z};
                });
      node.rotation_keys.step = step;
    }
    // Keys as glTF requires them (3.11): finite values at increasing times;
    // rotations are made unit.
    const std::string bad = "the animation of node \"" + name + "\" has ";
    auto check_times = [&](const std::vector<float>& times) {
      for (size_t i = 0; i < times.size(); ++i)
        if (!std::isfinite(times[i]) || (i > 0 && !(times[i] > times[i - 1])))
          fail(path_, bad + "key times that are not finite and increasing");
    };
    for (const Track<Vec3>* track : {&node.translation_keys, &node.scale_keys}) {
      check_times(track->times);
      for (Vec3 v : track->values)
        if (!is_finite(v)) fail(path_, bad + "a non-finite key");
    }
    check_times(node.rotation_keys.times);
    for (Quat& q : node.rotation_keys.values) {
      const float len = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
      if (!std::isfinite(len) || !(len > 0))
        fail(path_, bad + "a rotation key that is not a rotation");
      q = Quat{q.w / len, q.x / len, q.y / len, q.z / len};
    }
  }
  motion_->nodes.push_back(std::move(node));
  const auto index = uint32_t(motion_->nodes.size() - 1);
  motion_index_.emplace(n, index);
  return index;
}

const aiNodeAnim* Loader::path_channel(const std::string& name, const char* path,
                                       double* ticks_per_second, bool* step) const {
  *step = false;
  bool named = false;
  for (const GltfInfo::AnimatedPath& ap : gltf_.animated_paths) {
    if (ap.node != name) continue;
    named = true;
    if (ap.path != path || ap.animation >= scene_->mNumAnimations) continue;
    const aiAnimation* anim = scene_->mAnimations[ap.animation];
    for (unsigned c = 0; c < anim->mNumChannels; ++c) {
      if (anim->mChannels[c]->mNodeName.C_Str() != name) continue;
      *ticks_per_second = anim->mTicksPerSecond > 0 ? anim->mTicksPerSecond : 1.0;
      *step = ap.interpolation == "STEP";
      if (ap.interpolation == "CUBICSPLINE")
        spdlog::warn(
            "{}: the {} of node \"{}\" is animated by a CUBICSPLINE sampler; dofarm "
            "interpolates linearly between its keys (the spline's tangents are not read)",
            path_.string(), path, name);
      return anim->mChannels[c];
    }
  }
  if (named) return nullptr;  // the file's animations do not move this path
  const auto it = channels_.find(name);
  if (it == channels_.end()) return nullptr;
  *ticks_per_second = it->second.ticks_per_second;
  return it->second.keys;
}

// Node animation moves meshes and lights frame by frame (SceneMotion);
// what it cannot move is named in a warning: morph target weights, and
// skinned meshes (bones), which stay in their bind pose.
void Loader::finish_motion() {
  if (!motion_->parts.empty() || !motion_->lights.empty()) {
    if (!motion_->tangents.empty()) {
      motion_->tangents.resize(motion_->positions.size());
      motion_->bitangents.resize(motion_->positions.size());
    }
    out_->motion = motion_;
  }
  unsigned morph = 0, skinned = 0;
  for (unsigned a = 0; a < scene_->mNumAnimations; ++a)
    morph +=
        scene_->mAnimations[a]->mNumMorphMeshChannels + scene_->mAnimations[a]->mNumMeshChannels;
  for (unsigned m = 0; m < scene_->mNumMeshes; ++m) skinned += scene_->mMeshes[m]->mNumBones > 0;
  if (morph > 0)
    spdlog::warn("{}: {} morph-target animation channel(s) ignored: meshes keep their base shape",
                 path_.string(), morph);
  if (skinned > 0)
    spdlog::warn("{}: {} skinned mesh(es) rendered in their bind pose: skinning is not applied",
                 path_.string(), skinned);
}

// --- lights --------------------------------------------------------------------

void Loader::lights() {
  if (scene_->mNumLights == 0) return;
  if (!is_gltf(path_)) {
    // Other formats' light units are the exporter's guess; only glTF's are defined.
    spdlog::warn("{}: {} light(s) ignored: dofarm reads lights from glTF files only",
                 path_.string(), scene_->mNumLights);
    return;
  }
  for (unsigned i = 0; i < scene_->mNumLights; ++i) {
    const aiLight* al = scene_->mLights[i];
    const std::string name = al->mName.C_Str();
    // assimp names a glTF light after the node that holds it.
    const aiNode* node = scene_->mRootNode->FindNode(al->mName);
    if (!node) {
      spdlog::warn("{}: light \"{}\" is on no node; ignored", path_.string(), name);
      continue;
    }
    aiMatrix4x4 world;  // at the nodes' own transforms; pose() moves an animated one
    for (const aiNode* n = node; n; n = n->mParent) world = n->mTransformation * world;
    PunctualLight light;
    light.name = name;
    light.position = to_vec3(world * al->mPosition);
    // glTF: spot and directional lights shine down their node's -z (assimp's
    // mDirection); the direction ignores the node's scale.
    light.direction = normalize(to_vec3(aiMatrix3x3(world) * al->mDirection), Vec3(0, 0, -1));
    // assimp hands out colour x intensity, in candela (point, spot) or lux
    // (directional); see kLumensPerWatt for the conversion.
    light.intensity =
        Vec3(al->mColorDiffuse.r, al->mColorDiffuse.g, al->mColorDiffuse.b) / kLumensPerWatt;
    switch (al->mType) {
      case aiLightSource_POINT:
        light.type = PunctualLight::Type::kPoint;
        break;
      case aiLightSource_SPOT:
        light.type = PunctualLight::Type::kSpot;
        light.cos_inner = std::cos(al->mAngleInnerCone);
        light.cos_outer = std::cos(al->mAngleOuterCone);
        break;
      case aiLightSource_DIRECTIONAL:
        light.type = PunctualLight::Type::kDirectional;
        break;
      default:
        spdlog::warn("{}: light \"{}\" of assimp type {} ignored", path_.string(), name,
                     int(al->mType));
        continue;
    }
    const std::string which = "light " + std::to_string(i) + " (\"" + name + "\")";
    if (!is_finite(light.position) || !is_finite(light.intensity) ||
        !std::isfinite(light.cos_inner) || !std::isfinite(light.cos_outer))
      fail(path_, which + " has a non-finite value");
    if (light.intensity.x < 0 || light.intensity.y < 0 || light.intensity.z < 0)
      fail(path_, which + " has a negative intensity");
    if (max_component(light.intensity) > kMaxRadiance)
      fail(path_, which + " has intensity " + fmt::format("{:g}", max_component(light.intensity)) +
                      " (after dividing by 683 lm/W), above the bound kMaxRadiance = 1e12");
    if (moves(node)) {
      MovingLight moving;
      moving.light = uint32_t(out_->lights.size());
      moving.node = motion_node(node);
      moving.position = to_vec3(al->mPosition);
      moving.direction = to_vec3(al->mDirection);
      motion_->lights.push_back(moving);
    }
    out_->lights.push_back(std::move(light));
  }
}

// assimp's file access, with every file it opens noted (InputFileLog): the
// glTF's buffers, an OBJ's material library, whatever the format pulls in.
class RecordingIOSystem : public Assimp::DefaultIOSystem {
 public:
  Assimp::IOStream* Open(const char* file, const char* mode) override {
    Assimp::IOStream* stream = DefaultIOSystem::Open(file, mode);
    if (stream) note_input_file(file);
    return stream;
  }
};

}  // namespace

SceneData load_scene_data(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) fail(path, "no such file");
  GltfInfo gltf;
  if (is_gltf(path)) {
    gltf = read_gltf_info(path);
    check_extensions(path, gltf);
  }
  Assimp::Importer importer;
  importer.SetIOHandler(new RecordingIOSystem);  // the importer owns it
  // Smooth normals only where the file has none, and not across edges sharper
  // than 80 degrees so boxes stay boxes.
  importer.SetPropertyFloat(AI_CONFIG_PP_GSN_MAX_SMOOTHING_ANGLE, 80.0f);
  // No aiProcess_PreTransformVertices (it drops cameras' animation) and no
  // aiProcess_FindDegenerates (degenerate triangles stay: the renderer copes).
  // aiProcess_FlipUVs: assimp hands out OpenGL uvs (v = 0 at the bottom) for
  // every format; flipping gives back glTF's v = 0 at the top row.
  const aiScene* scene =
      importer.ReadFile(path.string(), aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                           aiProcess_GenSmoothNormals | aiProcess_FlipUVs);
  if (!scene || !scene->mRootNode) {
    std::string why = importer.GetErrorString();
    fail(path, "cannot read: " + (why.empty() ? std::string("assimp gives no reason") : why));
  }
  // assimp flags a file without meshes (an empty glTF, one with only a
  // camera) as incomplete, without an error message.
  if (scene->mNumMeshes == 0) fail(path, "the scene has no triangles (0 meshes)");
  if (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE) {
    std::string why = importer.GetErrorString();
    fail(path, "cannot read: " +
                   (why.empty() ? std::string("assimp reports the scene incomplete") : why));
  }
  SceneData out;
  out.source = path;
  Loader loader(path, scene, gltf, &out);
  loader.materials();
  loader.animation_channels();
  loader.node(scene->mRootNode, aiMatrix4x4());
  if (out.triangle_count() == 0)
    fail(path, "the scene has no triangles (" + std::to_string(scene->mNumMeshes) +
                   " meshes, only points or lines)");
  loader.camera_track();
  loader.lights();
  loader.finish_motion();
  // Normal maps need tangents, which need the texture coordinates they read.
  std::string no_uv;
  for (Material& m : out.materials) {
    if (!m.has_normal_map() || !(m.normal_map_set() == 1 ? out.uvs1 : out.uvs).empty()) continue;
    no_uv += (no_uv.empty() ? "\"" : ", \"") + m.name + "\"";
    m.normal_tex = -1;
    m.clearcoat_normal_tex = -1;
  }
  if (!no_uv.empty())
    spdlog::warn(
        "{}: normal maps ignored (the scene has no texture coordinates to orient them) in "
        "materials {}",
        path.string(), no_uv);
  for (const Material& m : out.materials)
    if (m.has_normal_map()) {
      compute_tangents(&out);
      const auto& given = loader.given_tangents();
      for (size_t i = 0; i < given.size() && i < out.tangents.size(); ++i)
        if (length(given[i].t) > 0.0f) out.tangents[i] = given[i];
      break;
    }
  return out;
}

void compute_tangents(SceneData* d) {
  const size_t n = d->positions.size();
  if (d->uvs.size() != n && d->uvs1.size() != n) {
    d->tangents.clear();
    return;
  }
  std::vector<Vec3> along_u(n, Vec3(0.0f)), up(n, Vec3(0.0f)), face_normal(n, Vec3(0.0f));
  for (size_t t = 0; t + 2 < d->indices.size(); t += 3) {
    const uint32_t i0 = d->indices[t], i1 = d->indices[t + 1], i2 = d->indices[t + 2];
    const Vec3 e1 = d->positions[i1] - d->positions[i0], e2 = d->positions[i2] - d->positions[i0];
    const Vec3 fn = cross(e1, e2);
    for (uint32_t i : {i0, i1, i2}) face_normal[i] += fn;
    // The set the triangle's normal map reads (glTF 3.7.2.1: tangents follow
    // the normal texture's texture coordinates).
    const uint32_t mat = t / 3 < d->tri_material.size() ? d->tri_material[t / 3] : 0;
    const bool set1 = mat < d->materials.size() && d->materials[mat].normal_map_set() == 1;
    const std::vector<Vec2>& uv = set1 && d->uvs1.size() == n ? d->uvs1 : d->uvs;
    if (uv.size() != n) continue;
    const Vec2 w1 = uv[i1] - uv[i0], w2 = uv[i2] - uv[i0];
    // e1 = w1.x dp/du + w1.y dp/dv, e2 likewise: solve for the derivatives.
    const float det = w1.x * w2.y - w2.x * w1.y;
    if (!(std::fabs(det) > 0.0f) || !std::isfinite(det)) continue;
    const float r = 1.0f / det;
    const Vec3 dpdu = (e1 * w2.y - e2 * w1.y) * r;
    const Vec3 dpdv = (e2 * w1.x - e1 * w2.x) * r;
    if (!is_finite(dpdu) || !is_finite(dpdv)) continue;
    // Each triangle's directions, weighted by its area.
    const float area = length(fn);
    const Vec3 tu = normalize(dpdu, Vec3(0.0f)) * area, tv = normalize(dpdv, Vec3(0.0f)) * area;
    for (uint32_t i : {i0, i1, i2}) {
      along_u[i] += tu;
      up[i] = up[i] - tv;
    }
  }
  d->tangents.assign(n, {});
  for (size_t i = 0; i < n; ++i) {
    Vec3 nrm = d->normals.size() == n ? d->normals[i] : Vec3(0.0f);
    if (!(length(nrm) > 0.0f)) nrm = normalize(face_normal[i], Vec3(0, 0, 1));
    Vec3 t = along_u[i] - nrm * dot(nrm, along_u[i]);
    if (!(length(t) > 1e-20f)) {
      // No uv extent: any direction in the tangent plane.
      const Vec3 a = std::fabs(nrm.x) < 0.9f ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
      t = a - nrm * dot(nrm, a);
    }
    t = normalize(t, Vec3(1, 0, 0));
    d->tangents[i].t = t;
    d->tangents[i].w = dot(cross(nrm, t), up[i]) < 0.0f ? -1.0f : 1.0f;
  }
}

}  // namespace dofarm::render
