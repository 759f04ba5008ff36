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
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <tuple>

#include "common/content_hash.h"
#include "common/error.h"
#include "common/exr_io.h"
#include "common/file_bytes.h"
#include "worker/render/foreign_cameras.h"
#include "worker/render/gltf_info.h"
#include "worker/render/scene_loader.h"
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

float cycles_spot_attenuation(float cos_angle, float cos_half_spot, float blend) {
  if (!(cos_angle > cos_half_spot)) return 0.0f;
  const float t = cos_angle - cos_half_spot;
  const float smooth = (1.0f - cos_half_spot) * blend;
  float a = cos_angle;
  if (smooth > 0 && t < smooth) {
    const float x = t / smooth;
    a *= x * x * (3.0f - 2.0f * x);
  }
  return a;
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

namespace detail {

bool is_gltf(const std::filesystem::path& path) {
  const std::string ext = lower_extension(path);
  return ext == ".gltf" || ext == ".glb";
}

const std::string& Loader::file_bytes() {
  if (!file_bytes_) file_bytes_ = read_file_bytes(path_);
  return *file_bytes_;
}

// Collada geometries placed without a material (collada_unbound_geometries)
// get the grey diffuse surface Blender renders an object without a material
// in (Cycles' default surface: a diffuse BSDF of 0.8), not the file's first
// material, which assimp 5.2 gives them.
static Material blender_default_surface() {
  Material m;
  m.name = "(no material)";
  m.base_color = Vec3(0.8f);
  m.metallic = 0.0f;
  m.roughness = 1.0f;
  m.specular = 0.0f;  // no specular layer: the base alone, a Lambert lobe
  return m;
}

bool Loader::from_blender() const {
  aiString generator;
  return !is_gltf(path_) && scene_->mMetaData &&
         scene_->mMetaData->Get("SourceAsset_Generator", generator) &&
         std::string(generator.C_Str()).rfind("Blender", 0) == 0;
}

void Loader::materials() {
  // Blender's FBX and Collada exporters write a Principled BSDF's Metallic
  // as the material's reflectivity (FBX ReflectionFactor, Collada
  // <reflectivity>), and its importers read it back so; assimp 5.2 passes it
  // on as the reflectivity and leaves the metallic factor unset. Other
  // exporters' reflectivity means something else (the weight of a Phong
  // material's mirror reflection), so it is read only from Blender's files
  // (from_blender()).
  const bool blender = from_blender();
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
    if (blender && am->Get(AI_MATKEY_METALLIC_FACTOR, value) != AI_SUCCESS &&
        am->Get(AI_MATKEY_REFLECTIVITY, value) == AI_SUCCESS && std::isfinite(value))
      m.metallic = std::clamp(value, 0.0f, 1.0f);
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
        spdlog::warn(
            "{}: material \"{}\": KHR_materials_ior ior {} is outside [1, 1e4]; "
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
    m.base_color_tex.index = texture(am, {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE}, true,
                                     /*with_alpha=*/m.alpha_mask);
    // glTF metallicRoughnessTexture: assimp 5.2 files it under UNKNOWN
    // (AI_MATKEY_GLTF_PBRMETALLICROUGHNESS_METALLICROUGHNESS_TEXTURE).
    m.metal_rough_tex.index = texture(am, {aiTextureType_UNKNOWN}, false);
    m.emission_tex.index = texture(am, {aiTextureType_EMISSIVE}, true);
    if (g) {
      // glTF normalTexture (assimp files it under NORMALS): linear values.
      // Other formats' bump and normal maps are not read.
      m.normal_tex.index = texture(am, {aiTextureType_NORMALS}, false);
      // The extensions' textures, linear (glTF: R transmission, R clearcoat,
      // G clearcoat roughness), only where the file names them.
      if (g->transmission_tex.present)
        m.transmission_tex.index = texture(am, {aiTextureType_TRANSMISSION}, false);
      if (g->clearcoat_tex.present)
        m.clearcoat_tex.index = texture(am, {aiTextureType_CLEARCOAT}, false, false, 0);
      if (g->clearcoat_rough_tex.present)
        m.clearcoat_rough_tex.index = texture(am, {aiTextureType_CLEARCOAT}, false, false, 1);
      // clearcoatNormalTexture (assimp: CLEARCOAT, 2), linear like normalTexture.
      // KHR_materials_specular's, which assimp 5.2 does not read: A
      // multiplies specularFactor, RGB (sRGB) specularColorFactor.
      const std::string which = "material " + std::to_string(i) + " (\"" + m.name + "\")";
      m.specular_tex.index =
          gltf_texture(g->specular_tex, false, /*with_alpha=*/true, which, "specularTexture");
      m.specular_color_tex.index =
          gltf_texture(g->specular_color_tex, true, false, which, "specularColorTexture");
      if (g->clearcoat_normal_tex.present) {
        m.clearcoat_normal_tex.index = texture(am, {aiTextureType_CLEARCOAT}, false, false, 2);
        m.clearcoat_normal_scale =
            std::isfinite(g->clearcoat_normal_scale) ? g->clearcoat_normal_scale : 1.0f;
      }
      // KHR_materials_sheen: colour (sRGB) in slot 0, roughness in the
      // alpha of slot 1 (often the same image).
      if (g->sheen_color_tex.present)
        m.sheen_color_tex.index = texture(am, {aiTextureType_SHEEN}, true, false, 0);
      if (g->sheen_rough_tex.present)
        m.sheen_rough_tex.index = texture(am, {aiTextureType_SHEEN}, true, /*with_alpha=*/true, 1);
      m.normal_scale = std::isfinite(g->normal_scale) ? g->normal_scale : 1.0f;
      // Each slot's transform and texture coordinate set (0 or 1; a
      // higher set is named in a warning and TEXCOORD_0 read instead).
      const std::tuple<const char*, const GltfTextureInfo*, UvTransform*> slots[] = {
          {"baseColorTexture", &g->base_color, &m.base_color_tex.uv},
          {"metallicRoughnessTexture", &g->metal_rough, &m.metal_rough_tex.uv},
          {"emissiveTexture", &g->emission, &m.emission_tex.uv},
          {"normalTexture", &g->normal, &m.normal_tex.uv},
          {"transmissionTexture", &g->transmission_tex, &m.transmission_tex.uv},
          {"clearcoatTexture", &g->clearcoat_tex, &m.clearcoat_tex.uv},
          {"clearcoatRoughnessTexture", &g->clearcoat_rough_tex, &m.clearcoat_rough_tex.uv},
          {"sheenColorTexture", &g->sheen_color_tex, &m.sheen_color_tex.uv},
          {"sheenRoughnessTexture", &g->sheen_rough_tex, &m.sheen_rough_tex.uv},
          {"clearcoatNormalTexture", &g->clearcoat_normal_tex, &m.clearcoat_normal_tex.uv},
          {"specularTexture", &g->specular_tex, &m.specular_tex.uv},
          {"specularColorTexture", &g->specular_color_tex, &m.specular_color_tex.uv}};
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
  if (lower_extension(path_) == ".dae") {
    unbound_geometries_ = collada_unbound_geometries(file_bytes());
    if (!unbound_geometries_.empty()) {
      unbound_material_ = uint32_t(out_->materials.size());
      out_->materials.push_back(blender_default_surface());
    }
  }
}

void Loader::check_material(const Material& m, unsigned index) const {
  const std::string which = "material " + std::to_string(index) + " (\"" + m.name + "\")";
  bool ok = is_finite(m.base_color) && is_finite(m.emission) && std::isfinite(m.metallic) &&
            std::isfinite(m.roughness);
  if (!ok) fail(path_, which + " has a non-finite value");
  // An emission texture multiplies the factor: its brightest texel counts
  // (an 8-bit one is at most 1; an HDR one loaded for an OBJ may be more).
  float peak = max_component(m.emission);
  if (m.emission_tex.present() && peak > 0) {
    float texel = 0;
    for (float v : out_->textures[m.emission_tex.index].rgb) texel = std::max(texel, v);
    peak *= texel;
  }
  if (!(peak <= kMaxRadiance))
    fail(path_, which + " emits radiance " + fmt::format("{:g}", peak) +
                    ", above the bound kMaxRadiance = 1e12");
}

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
  const uint32_t material =
      unbound_geometries_.count(m->mName.C_Str()) ? unbound_material_ : m->mMaterialIndex;
  const bool wants_uv1 = material < out_->materials.size() && out_->materials[material].reads_uv1();
  const bool has_uv1 = wants_uv1 && m->HasTextureCoords(1);
  if (wants_uv1 && out_->uvs1.empty()) out_->uvs1.assign(base, Vec2(0, 0));
  const bool keep_uv1 = wants_uv1 || !out_->uvs1.empty();
  if (wants_uv1 && !has_uv1)
    spdlog::warn(
        "{}: mesh \"{}\" of node \"{}\" has no TEXCOORD_1, which its material \"{}\" reads; "
        "TEXCOORD_0 used",
        path_.string(), m->mName.C_Str(), node_name, out_->materials[material].name);
  // Morph targets (glTF 3.7.2.2; assimp 5.2: aiAnimMesh, each target's
  // vertices as base + offset, mWeight the mesh's default weight): the
  // vertices below are the mesh at its default weights; where an animation
  // drives the weights, pose() morphs them per frame (SceneMotion::morphs).
  double morph_tps = 1.0;
  unsigned morph_animation = 0;
  const aiMeshMorphAnim* morph_keys =
      m->mNumAnimMeshes > 0 ? morph_channel(node_name, &morph_tps, &morph_animation) : nullptr;
  auto target_ok = [m](unsigned k, bool normals) {
    const aiAnimMesh* a = m->mAnimMeshes[k];
    return a->mNumVertices == m->mNumVertices &&
           (normals ? a->mNormals != nullptr && m->HasNormals() : a->mVertices != nullptr);
  };
  auto morphed = [&](unsigned v, bool normals) {
    const aiVector3D* base_of = normals ? m->mNormals : m->mVertices;
    aiVector3D x = base_of[v];
    for (unsigned k = 0; k < m->mNumAnimMeshes; ++k) {
      if (!target_ok(k, normals)) continue;
      const aiAnimMesh* a = m->mAnimMeshes[k];
      x += ((normals ? a->mNormals : a->mVertices)[v] - base_of[v]) * a->mWeight;
    }
    return x;
  };
  // The mesh at its default weights, in its own space (pose() needs it too
  // for a moving node whose weights no animation drives).
  std::vector<aiVector3D> rest_positions(m->mNumVertices), rest_normals;
  for (unsigned v = 0; v < m->mNumVertices; ++v) rest_positions[v] = morphed(v, false);
  if (m->HasNormals()) {
    rest_normals.resize(m->mNumVertices);
    for (unsigned v = 0; v < m->mNumVertices; ++v) rest_normals[v] = morphed(v, true);
  }
  for (unsigned v = 0; v < m->mNumVertices; ++v) {
    Vec3 p = to_vec3(world * rest_positions[v]);
    if (!is_finite(p)) {
      fail(path_, "mesh \"" + std::string(m->mName.C_Str()) + "\" of node \"" + node_name +
                      "\": vertex " + std::to_string(v) + " is not finite");
    }
    out_->positions.push_back(p);
    // aiProcess_GenSmoothNormals fills in normals where the file has none.
    const Vec3 n = normalize(
        m->HasNormals() ? to_vec3(normal_matrix * rest_normals[v]) : Vec3(0.0f), Vec3(0.0f));
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
  // Animated morph weights: the base and each target's offsets; else the
  // mesh at its default weights.
  for (unsigned v = 0; v < m->mNumVertices; ++v) {
    mo.positions.push_back(to_vec3(morph_keys ? m->mVertices[v] : rest_positions[v]));
    mo.normals.push_back(
        m->HasNormals()
            ? normalize(to_vec3(morph_keys ? m->mNormals[v] : rest_normals[v]), Vec3(0.0f))
            : Vec3(0.0f));
    if (tangents) {
      mo.tangents.push_back(to_vec3(m->mTangents[v]));
      mo.bitangents.push_back(to_vec3(m->mBitangents[v]));
    }
  }
  if (m->HasBones()) part.skin = skin(m, node_name);
  if (morph_keys) {
    Morph morph;
    for (unsigned k = 0; k < m->mNumAnimMeshes; ++k) {
      const aiAnimMesh* a = m->mAnimMeshes[k];
      std::vector<Vec3> dp, dn;
      for (unsigned v = 0; target_ok(k, false) && v < m->mNumVertices; ++v)
        dp.push_back(to_vec3(a->mVertices[v] - m->mVertices[v]));
      if (dp.empty()) dp.assign(m->mNumVertices, Vec3(0.0f));
      for (unsigned v = 0; target_ok(k, true) && v < m->mNumVertices; ++v)
        dn.push_back(to_vec3(a->mNormals[v] - m->mNormals[v]));
      morph.positions.push_back(std::move(dp));
      morph.normals.push_back(std::move(dn));
    }
    for (unsigned i = 0; i < morph_keys->mNumKeys; ++i) {
      const aiMeshMorphKey& key = morph_keys->mKeys[i];
      std::vector<float> w(m->mNumAnimMeshes, 0.0f);
      for (unsigned j = 0; j < key.mNumValuesAndWeights; ++j)
        if (key.mValues[j] < w.size()) w[key.mValues[j]] = float(key.mWeights[j]);
      for (float x : w)
        if (!std::isfinite(x))
          fail(path_,
               "the morph weights of node \"" + std::string(node_name) + "\" are not finite");
      const float t = float(key.mTime / morph_tps);
      if (!std::isfinite(t) || (i > 0 && !(t > morph.weights.times.back())))
        fail(path_, "the morph weights of node \"" + std::string(node_name) +
                        "\" have key times that are not finite and increasing");
      morph.weights.times.push_back(t);
      morph.weights.values.push_back(std::move(w));
    }
    // The sampler's interpolation, which assimp 5.2 does not keep: STEP
    // holds each key until the next; CUBICSPLINE follows the Hermite spline
    // of glTF Appendix C through the keys and their tangents, read from the
    // file (per key the in-tangents of all targets, their values, their
    // out-tangents).
    if (const GltfInfo::AnimatedPath* ap = weights_path(node_name, morph_animation)) {
      morph.weights.step = ap->interpolation == "STEP";
      const size_t targets = m->mNumAnimMeshes, keys = morph.weights.times.size();
      if (!ap->cubic.empty() && ap->cubic.size() != 3 * targets * keys) {
        spdlog::warn(
            "{}: the CUBICSPLINE weights of node \"{}\" have {} floats for {} keys of {} "
            "targets; they are interpolated linearly",
            path_.string(), node_name, ap->cubic.size(), keys, targets);
      } else if (!ap->cubic.empty()) {
        auto slice = [&](size_t k, size_t part) {
          const float* f = &ap->cubic[(3 * k + part) * targets];
          for (size_t j = 0; j < targets; ++j)
            if (!std::isfinite(f[j]))
              fail(path_, "the CUBICSPLINE weights of node \"" + std::string(node_name) +
                              "\" are not finite");
          return std::vector<float>(f, f + targets);
        };
        for (size_t k = 0; k < keys; ++k) {
          morph.weights.in_tangents.push_back(slice(k, 0));
          morph.weights.values[k] = slice(k, 1);
          morph.weights.out_tangents.push_back(slice(k, 2));
        }
      }
    }
    if (!morph.weights.empty()) {
      motion_->morphs.push_back(std::move(morph));
      part.morph = int(motion_->morphs.size() - 1);
    }
  }
  mo.parts.push_back(part);
}

int Loader::skin(const aiMesh* m, const char* node_name) {
  const std::string which =
      "mesh \"" + std::string(m->mName.C_Str()) + "\" of node \"" + node_name + "\"";
  Skin skin;
  std::vector<std::vector<Skin::Influence>> per_vertex(m->mNumVertices);
  for (unsigned b = 0; b < m->mNumBones; ++b) {
    const aiBone* bone = m->mBones[b];
    const aiNode* joint = scene_->mRootNode->FindNode(bone->mName);
    if (!joint)
      fail(path_, which + ": joint \"" + std::string(bone->mName.C_Str()) + "\" is no node");
    skin.joints.push_back(motion_node(joint));
    // assimp's bone offset is glTF's inverse bind matrix.
    skin.inverse_bind.push_back(to_affine(bone->mOffsetMatrix));
    for (unsigned w = 0; w < bone->mNumWeights; ++w) {
      const aiVertexWeight& vw = bone->mWeights[w];
      if (vw.mVertexId < m->mNumVertices && std::isfinite(vw.mWeight) && vw.mWeight > 0.0f)
        per_vertex[vw.mVertexId].push_back({b, vw.mWeight});
    }
  }
  // Weights summing to 1 (glTF 3.7.3.3 asks the file for it; exporters
  // round), so a vertex neither grows nor shrinks towards the origin.
  skin.first.push_back(0);
  for (const auto& influences : per_vertex) {
    float sum = 0.0f;
    for (const Skin::Influence& i : influences) sum += i.weight;
    for (Skin::Influence i : influences) {
      i.weight /= sum;
      skin.influences.push_back(i);
    }
    skin.first.push_back(uint32_t(skin.influences.size()));
  }
  motion_->skins.push_back(std::move(skin));
  return int(motion_->skins.size() - 1);
}

}  // namespace detail

namespace {

using detail::fail;
using detail::is_gltf;
using detail::Loader;

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

SceneData load_scene_data(const std::filesystem::path& path, const std::string& camera) {
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
  // aiProcess_GlobalScale applies the file's own unit, which only FBX
  // declares (UnitScaleFactor, centimetres per unit): Blender writes FBX in
  // centimetres, and without it a Blender scene came out 100 times larger
  // than in Blender, its depths and its job's focal distance and aperture in
  // centimetres. glTF is in metres already (the step does nothing).
  const aiScene* scene = importer.ReadFile(
      path.string(), aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                         aiProcess_GenSmoothNormals | aiProcess_FlipUVs | aiProcess_GlobalScale);
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
  out.generator = gltf.generator;
  Loader loader(path, scene, gltf, &out);
  loader.materials();
  loader.animation_channels();
  loader.node(scene->mRootNode, aiMatrix4x4());
  if (out.triangle_count() == 0)
    fail(path, "the scene has no triangles (" + std::to_string(scene->mNumMeshes) +
                   " meshes, only points or lines)");
  loader.camera_track(camera);
  loader.lights();
  loader.finish_motion();
  // Normal maps need tangents, which need the texture coordinates they read.
  std::string no_uv;
  for (Material& m : out.materials) {
    if (!m.has_normal_map() || !(m.normal_map_set() == 1 ? out.uvs1 : out.uvs).empty()) continue;
    no_uv += (no_uv.empty() ? "\"" : ", \"") + m.name + "\"";
    m.normal_tex.index = -1;
    m.clearcoat_normal_tex.index = -1;
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
