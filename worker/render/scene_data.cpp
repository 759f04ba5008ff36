#include "worker/render/scene_data.h"

#include <assimp/GltfMaterial.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <assimp/DefaultIOSystem.h>
#include <assimp/Importer.hpp>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "common/content_hash.h"
#include "common/error.h"
#include "common/exr_io.h"

namespace dofarm::render {

// ---------------------------------------------------------------------------
// Texture

Vec3 Texture::lookup(Vec2 uv) const {
  if (width <= 0 || height <= 0) return Vec3(1.0f);
  // Texel centres sit at (i + 0.5) / size, so a texture of one texel is
  // constant and uv 0 and 1 blend the two border texels (repeat wrap).
  auto axis = [](float t, int size, int* i0, int* i1, float* frac) {
    if (!std::isfinite(t)) t = 0.0f;
    t -= std::floor(t);  // into [0, 1) first, so huge uvs keep their precision
    float x = t * static_cast<float>(size) - 0.5f;
    float fx = std::floor(x);
    *frac = x - fx;
    int i = static_cast<int>(fx);
    *i0 = (i % size + size) % size;
    *i1 = (*i0 + 1) % size;
  };
  int x0, x1, y0, y1;
  float fx, fy;
  axis(uv.x, width, &x0, &x1, &fx);
  axis(uv.y, height, &y0, &y1, &fy);  // v = 0 is row 0, the top row (glTF)
  auto texel = [&](int x, int y) {
    const float* p = &rgb[(static_cast<size_t>(y) * width + x) * 3];
    return Vec3(p[0], p[1], p[2]);
  };
  return lerp(lerp(texel(x0, y0), texel(x1, y0), fx), lerp(texel(x0, y1), texel(x1, y1), fx), fy);
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

// KHR_materials_emissive_strength per glTF material (1 where absent), with
// the material names to check that assimp kept the order. assimp 5.2.5 does
// not import the extension (it drops it silently), so it is read here.
struct GltfEmissive {
  std::vector<float> strength;
  std::vector<std::string> name;
};

GltfEmissive read_gltf_emissive_strength(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::string json_text = bytes;
  if (bytes.size() >= 20 && bytes.compare(0, 4, "glTF") == 0) {
    // .glb: 12-byte header, then the JSON chunk (length, type "JSON", data).
    uint32_t length = 0;
    std::memcpy(&length, bytes.data() + 12, 4);
    if (bytes.compare(16, 4, "JSON") != 0 || 20 + size_t{length} > bytes.size()) return {};
    json_text = bytes.substr(20, length);
  }
  GltfEmissive out;
  auto doc = nlohmann::json::parse(json_text, nullptr, /*allow_exceptions=*/false);
  if (!doc.is_object() || !doc.contains("materials") || !doc["materials"].is_array()) return out;
  for (const auto& m : doc["materials"]) {
    float strength = 1.0f;
    const auto* ext = m.contains("extensions") ? &m["extensions"] : nullptr;
    if (ext && ext->contains("KHR_materials_emissive_strength")) {
      const auto& e = (*ext)["KHR_materials_emissive_strength"];
      if (e.contains("emissiveStrength") && e["emissiveStrength"].is_number()) {
        strength = e["emissiveStrength"].get<float>();
      }
    }
    out.strength.push_back(strength);
    out.name.push_back(m.contains("name") && m["name"].is_string() ? m["name"].get<std::string>()
                                                                   : std::string());
  }
  return out;
}

Vec3 to_vec3(const aiVector3D& v) { return {v.x, v.y, v.z}; }
Vec3 to_vec3(const aiColor4D& c) { return {c.r, c.g, c.b}; }

class Loader {
 public:
  Loader(const std::filesystem::path& path, const aiScene* scene, SceneData* out)
      : path_(path), scene_(scene), out_(out) {}

  void materials() {
    GltfEmissive gltf;
    if (is_gltf(path_)) gltf = read_gltf_emissive_strength(path_);
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
        } else if (i < gltf.strength.size() && gltf.name[i] == m.name) {
          strength = gltf.strength[i];
        }
        m.emission = to_vec3(color) * strength;
      }
      // Exporters write IOR 1 (or 0) to mean "not set"; a dielectric of IOR 1
      // would have no specular lobe at all, so those fall back to the default.
      if (am->Get(AI_MATKEY_REFRACTI, value) == AI_SUCCESS && value > 1.0f &&
          std::isfinite(value)) {
        m.ior = value;
      }
      m.base_color_tex = texture(am, {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE}, true);
      // glTF metallicRoughnessTexture: assimp 5.2 files it under UNKNOWN
      // (AI_MATKEY_GLTF_PBRMETALLICROUGHNESS_METALLICROUGHNESS_TEXTURE).
      m.metal_rough_tex = texture(am, {aiTextureType_UNKNOWN}, false);
      m.emission_tex = texture(am, {aiTextureType_EMISSIVE}, true);
      check_finite(m, i);
      out_->materials.push_back(std::move(m));
    }
  }

  void node(const aiNode* node, const aiMatrix4x4& parent) {
    const aiMatrix4x4 world = parent * node->mTransformation;
    for (unsigned k = 0; k < node->mNumMeshes; ++k) {
      mesh(scene_->mMeshes[node->mMeshes[k]], world, node->mName.C_Str());
    }
    for (unsigned c = 0; c < node->mNumChildren; ++c) this->node(node->mChildren[c], world);
  }

  void camera_track();

 private:
  int texture(const aiMaterial* am, std::initializer_list<aiTextureType> types, bool srgb);
  void mesh(const aiMesh* m, const aiMatrix4x4& world, const char* node_name);
  void check_finite(const Material& m, unsigned index) const {
    bool ok = is_finite(m.base_color) && is_finite(m.emission) && std::isfinite(m.metallic) &&
              std::isfinite(m.roughness);
    if (!ok)
      fail(path_,
           "material " + std::to_string(index) + " (\"" + m.name + "\") has a non-finite value");
  }

  const std::filesystem::path& path_;
  const aiScene* scene_;
  SceneData* out_;
  std::map<std::pair<std::string, bool>, int> texture_index_;  // shared textures load once
};

int Loader::texture(const aiMaterial* am, std::initializer_list<aiTextureType> types, bool srgb) {
  for (aiTextureType type : types) {
    aiString file;
    if (am->GetTexture(type, 0, &file) != AI_SUCCESS) continue;
    std::string name = file.C_Str();
    if (name.empty()) continue;
    if (name[0] == '*' || scene_->GetEmbeddedTexture(file.C_Str()) != nullptr) {
      fail(path_, "texture \"" + name.substr(0, 40) +
                      "\" is embedded in the file; dofarm reads textures from image files next to "
                      "the scene (export with separate textures)");
    }
    std::filesystem::path tex_path = path_.parent_path() / name;
    auto key = std::make_pair(tex_path.lexically_normal().string(), srgb);
    if (auto it = texture_index_.find(key); it != texture_index_.end()) return it->second;
    RgbImage image;
    try {
      image = load_rgb_image(tex_path, srgb);
    } catch (const std::exception& e) {
      fail(path_, std::string("texture: ") + e.what());
    }
    Texture tex;
    tex.width = image.width;
    tex.height = image.height;
    tex.rgb = std::move(image.rgb);
    tex.name = name;
    out_->textures.push_back(std::move(tex));
    int index = static_cast<int>(out_->textures.size()) - 1;
    texture_index_.emplace(key, index);
    return index;
  }
  return -1;
}

void Loader::mesh(const aiMesh* m, const aiMatrix4x4& world, const char* node_name) {
  // Normals transform by the inverse transpose, so non-uniform scale keeps
  // them perpendicular to the surface.
  aiMatrix3x3 normal_matrix(world);
  const bool mirrored = normal_matrix.Determinant() < 0;
  normal_matrix.Inverse().Transpose();
  const auto base = static_cast<uint32_t>(out_->positions.size());
  const bool has_uv = m->HasTextureCoords(0);
  if (has_uv && out_->uvs.empty()) out_->uvs.assign(base, Vec2(0, 0));
  for (unsigned v = 0; v < m->mNumVertices; ++v) {
    Vec3 p = to_vec3(world * m->mVertices[v]);
    if (!is_finite(p)) {
      fail(path_, "mesh \"" + std::string(m->mName.C_Str()) + "\" of node \"" + node_name +
                      "\": vertex " + std::to_string(v) + " is not finite");
    }
    out_->positions.push_back(p);
    // aiProcess_GenSmoothNormals fills in normals where the file has none.
    Vec3 n = m->HasNormals() ? to_vec3(normal_matrix * m->mNormals[v]) : Vec3(0.0f);
    out_->normals.push_back(normalize(n, Vec3(0.0f)));
    if (has_uv) {
      out_->uvs.emplace_back(m->mTextureCoords[0][v].x, m->mTextureCoords[0][v].y);
    } else if (!out_->uvs.empty()) {
      out_->uvs.emplace_back(0.0f, 0.0f);
    }
  }
  const uint32_t material = m->mMaterialIndex;
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
}

// --- camera animation --------------------------------------------------------

// Linear interpolation of assimp key arrays at `time` (ticks), clamped at the
// ends, as glTF's LINEAR sampler does.
template <typename Key, typename Blend>
auto sample_keys(const Key* keys, unsigned count, double time, Blend blend) {
  if (time <= keys[0].mTime || count == 1) return keys[0].mValue;
  for (unsigned i = 1; i < count; ++i) {
    if (time <= keys[i].mTime) {
      double span = keys[i].mTime - keys[i - 1].mTime;
      float t = span > 0 ? static_cast<float>((time - keys[i - 1].mTime) / span) : 1.0f;
      return blend(keys[i - 1].mValue, keys[i].mValue, t);
    }
  }
  return keys[count - 1].mValue;
}

aiMatrix4x4 local_transform(const aiNode* node, const aiNodeAnim* channel, double ticks) {
  if (!channel) return node->mTransformation;
  aiVector3D scaling(1, 1, 1), position(0, 0, 0);
  aiQuaternion rotation;
  node->mTransformation.Decompose(scaling, rotation, position);
  auto lerp3 = [](const aiVector3D& a, const aiVector3D& b, float t) { return a + (b - a) * t; };
  if (channel->mNumPositionKeys > 0) {
    position = sample_keys(channel->mPositionKeys, channel->mNumPositionKeys, ticks, lerp3);
  }
  if (channel->mNumRotationKeys > 0) {
    rotation = sample_keys(channel->mRotationKeys, channel->mNumRotationKeys, ticks,
                           [](const aiQuaternion& a, const aiQuaternion& b, float t) {
                             aiQuaternion q;
                             aiQuaternion::Interpolate(q, a, b, t);
                             return q.Normalize();
                           });
  }
  if (channel->mNumScalingKeys > 0) {
    scaling = sample_keys(channel->mScalingKeys, channel->mNumScalingKeys, ticks, lerp3);
  }
  return aiMatrix4x4(scaling, rotation, position);
}

void Loader::camera_track() {
  if (scene_->mNumCameras == 0) return;
  // The first camera is the scene's camera; others are ignored.
  const aiCamera* cam = scene_->mCameras[0];
  const aiNode* cam_node = scene_->mRootNode->FindNode(cam->mName);
  if (!cam_node) return;
  std::vector<const aiNode*> chain;  // root ... camera node
  for (const aiNode* n = cam_node; n; n = n->mParent) chain.insert(chain.begin(), n);

  // The first animation that moves the camera or one of its parents.
  const aiAnimation* anim = nullptr;
  std::vector<const aiNodeAnim*> channels(chain.size(), nullptr);
  for (unsigned a = 0; a < scene_->mNumAnimations && !anim; ++a) {
    const aiAnimation* candidate = scene_->mAnimations[a];
    for (unsigned c = 0; c < candidate->mNumChannels; ++c) {
      const aiNodeAnim* ch = candidate->mChannels[c];
      for (size_t k = 0; k < chain.size(); ++k) {
        if (ch->mNodeName == chain[k]->mName) {
          channels[k] = ch;
          anim = candidate;
        }
      }
    }
  }
  const double ticks_per_second = anim && anim->mTicksPerSecond > 0 ? anim->mTicksPerSecond : 1.0;
  std::set<double> ticks;  // union of all key times on the chain
  for (const aiNodeAnim* ch : channels) {
    if (!ch) continue;
    for (unsigned i = 0; i < ch->mNumPositionKeys; ++i) ticks.insert(ch->mPositionKeys[i].mTime);
    for (unsigned i = 0; i < ch->mNumRotationKeys; ++i) ticks.insert(ch->mRotationKeys[i].mTime);
    for (unsigned i = 0; i < ch->mNumScalingKeys; ++i) ticks.insert(ch->mScalingKeys[i].mTime);
  }
  if (ticks.empty()) ticks.insert(0.0);  // a static camera: one key

  // A glTF camera sits at its node's origin looking down -z with +y up
  // (glTF 2.0, 3.10.1). assimp 5.2.5 also copies the node's translation into
  // aiCamera::mPosition, which would apply it twice, so for glTF the camera's
  // own frame is taken from the spec rather than from aiCamera.
  const bool gltf = is_gltf(path_);
  const aiVector3D cam_position = gltf ? aiVector3D(0, 0, 0) : cam->mPosition;
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
  for (double t : ticks) {
    aiMatrix4x4 world;
    for (size_t k = 0; k < chain.size(); ++k)
      world = world * local_transform(chain[k], channels[k], t);
    aiMatrix3x3 rot(world);
    auto apply = [&](Vec3 v) { return to_vec3(rot * aiVector3D(v.x, v.y, v.z)); };
    // Orthonormalise: scale in the hierarchy must not leak into the rotation.
    Vec3 w_back = normalize(apply(back));
    Vec3 w_right = normalize(cross(apply(up), w_back));
    Vec3 w_up = cross(w_back, w_right);
    CameraTrackKey key;
    key.time = static_cast<float>(t / ticks_per_second);
    key.position = to_vec3(world * cam_position);
    key.rotation = quat_from_axes(w_right, w_up, w_back);
    key.yfov_deg = yfov * 180.0f / kPi;
    key.aspect = cam->mAspect > 0 ? cam->mAspect : 0.0f;
    if (!is_finite(key.position) || !std::isfinite(key.yfov_deg)) {
      fail(path_, "camera \"" + std::string(cam->mName.C_Str()) + "\" has a non-finite transform");
    }
    out_->camera_track.push_back(key);
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
  if (!scene || !scene->mRootNode || (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE)) {
    fail(path, std::string("cannot read: ") + importer.GetErrorString());
  }
  SceneData out;
  out.source = path;
  Loader loader(path, scene, &out);
  loader.materials();
  loader.node(scene->mRootNode, aiMatrix4x4());
  if (out.triangle_count() == 0) fail(path, "the scene has no triangles");
  loader.camera_track();
  return out;
}

}  // namespace dofarm::render
