#include "worker/render/gltf_info.h"

#include <sodium.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "common/error.h"
#include "common/file_bytes.h"

namespace dofarm::render {

namespace {

// The extensions whose content dofarm reads (assimp: KHR_materials_ior,
// KHR_lights_punctual; here: the others).
const std::set<std::string>& implemented_extensions() {
  static const std::set<std::string> names = {
      "KHR_materials_clearcoat", "KHR_materials_emissive_strength",
      "KHR_materials_sheen",     "KHR_materials_ior",
      "KHR_materials_specular",  "KHR_materials_transmission",
      "KHR_materials_volume",    "KHR_lights_punctual",
      "KHR_texture_transform"};
  return names;
}

float number_or(const nlohmann::json& obj, const char* key, float fallback) {
  if (!obj.is_object() || !obj.contains(key) || !obj[key].is_number()) return fallback;
  return obj[key].get<float>();
}

Vec2 vec2_or(const nlohmann::json& obj, const char* key, Vec2 fallback) {
  if (!obj.is_object() || !obj.contains(key) || !obj[key].is_array() || obj[key].size() != 2 ||
      !obj[key][0].is_number() || !obj[key][1].is_number())
    return fallback;
  return {obj[key][0].get<float>(), obj[key][1].get<float>()};
}

// An extension's number as written: untouched when the key is absent, NaN
// when it is there but not a number (the loader names it in a warning).
void read_number(const nlohmann::json& ext, const char* key, double* out) {
  if (ext.contains(key)) *out = ext[key].is_number() ? ext[key].get<double>() : NAN;
}

// The same for an RGB array: NaN in every channel when it is not three
// numbers.
void read_color(const nlohmann::json& ext, const char* key, double out[3]) {
  if (!ext.contains(key)) return;
  const auto& c = ext[key];
  const bool ok =
      c.is_array() && c.size() == 3 && c[0].is_number() && c[1].is_number() && c[2].is_number();
  for (int k = 0; k < 3; ++k) out[k] = ok ? c[k].get<double>() : NAN;
}

// A textureInfo object (glTF 5.22) with its optional KHR_texture_transform.
GltfTextureInfo read_texture_info(const nlohmann::json& info) {
  GltfTextureInfo out;
  if (!info.is_object()) return out;
  out.present = true;
  if (info.contains("index") && info["index"].is_number_integer())
    out.index = info["index"].get<int>();
  out.tex_coord = static_cast<int>(number_or(info, "texCoord", 0));
  if (info.contains("extensions") && info["extensions"].is_object() &&
      info["extensions"].contains("KHR_texture_transform")) {
    const auto& t = info["extensions"]["KHR_texture_transform"];
    out.transform =
        UvTransform::from_gltf(vec2_or(t, "offset", Vec2(0, 0)), number_or(t, "rotation", 0),
                               vec2_or(t, "scale", Vec2(1, 1)));
    if (t.is_object() && t.contains("texCoord") && t["texCoord"].is_number_integer())
      out.tex_coord = t["texCoord"].get<int>();
  }
  return out;
}

// The file's textures as GltfTextureRef (glTF 2.0, 5.29 textures, 5.18
// images, 5.26 samplers; 9728 is NEAREST, 33071 CLAMP_TO_EDGE, 33648
// MIRRORED_REPEAT).
std::vector<GltfTextureRef> texture_refs(const nlohmann::json& doc) {
  const auto& images =
      doc.contains("images") && doc["images"].is_array() ? doc["images"] : nlohmann::json::array();
  std::vector<GltfTextureRef> out;
  if (!doc.contains("textures") || !doc["textures"].is_array()) return out;
  for (const auto& t : doc["textures"]) {
    GltfTextureRef ref;
    if (t.is_object() && t.contains("source") && t["source"].is_number_integer()) {
      const int source = t["source"].get<int>();
      if (source >= 0 && size_t(source) < images.size() && images[size_t(source)].is_object()) {
        const auto& img = images[size_t(source)];
        const std::string uri =
            img.contains("uri") && img["uri"].is_string() ? img["uri"].get<std::string>() : "";
        ref.image = source;
        ref.held = img.contains("bufferView") || uri.compare(0, 5, "data:") == 0;
        ref.name = ref.held ? "image " + std::to_string(source) : uri;
      }
    }
    if (t.is_object() && t.contains("sampler") && t["sampler"].is_number_integer() &&
        doc.contains("samplers") && doc["samplers"].is_array()) {
      const int s = t["sampler"].get<int>();
      if (s >= 0 && size_t(s) < doc["samplers"].size() && doc["samplers"][size_t(s)].is_object()) {
        const auto& sampler = doc["samplers"][size_t(s)];
        auto wrap = [&](const char* key) {
          const float mode = number_or(sampler, key, 10497);
          return mode == 33071   ? TextureWrap::kClamp
                 : mode == 33648 ? TextureWrap::kMirror
                                 : TextureWrap::kRepeat;
        };
        ref.sampler.nearest = number_or(sampler, "magFilter", 9729) == 9728;
        ref.sampler.wrap_u = wrap("wrapS");
        ref.sampler.wrap_v = wrap("wrapT");
      }
    }
    out.push_back(std::move(ref));
  }
  return out;
}

std::vector<std::string> string_list(const nlohmann::json& doc, const char* key) {
  std::vector<std::string> out;
  if (!doc.contains(key) || !doc[key].is_array()) return out;
  for (const auto& v : doc[key])
    if (v.is_string()) out.push_back(v.get<std::string>());
  return out;
}

}  // namespace

namespace {

// A glTF file's JSON and, for a .glb, its binary chunk (glTF 2.0, 4.4:
// a 12-byte header, then chunks of length, type and data); false where a
// .glb's JSON chunk is not whole.
bool split_gltf(const std::string& bytes, std::string* json, std::string* bin) {
  if (bytes.size() < 20 || bytes.compare(0, 4, "glTF") != 0) {
    *json = bytes;
    return true;
  }
  uint32_t length = 0;
  std::memcpy(&length, bytes.data() + 12, 4);
  if (bytes.compare(16, 4, "JSON") != 0 || 20 + size_t{length} > bytes.size()) return false;
  *json = bytes.substr(20, length);
  const size_t at = 20 + size_t{length};
  if (at + 8 <= bytes.size() && bytes.compare(at + 4, 4, std::string("BIN\0", 4)) == 0) {
    uint32_t bin_length = 0;
    std::memcpy(&bin_length, bytes.data() + at, 4);
    if (at + 8 + size_t{bin_length} <= bytes.size()) *bin = bytes.substr(at + 8, bin_length);
  }
  return true;
}

// The payload of a base64 data: URI.
std::string data_uri_bytes(const std::string& uri, const std::string& what) {
  const size_t comma = uri.find(',');
  if (comma == std::string::npos || uri.rfind(";base64", comma) == std::string::npos)
    throw RuntimeError(what + ": a data: URI that is not base64");
  const std::string text = uri.substr(comma + 1);
  std::string out(text.size() / 4 * 3 + 3, '\0');
  size_t length = 0;
  if (sodium_base642bin(reinterpret_cast<unsigned char*>(out.data()), out.size(), text.data(),
                        text.size(), " \r\n", &length, nullptr,
                        sodium_base64_VARIANT_ORIGINAL) != 0)
    throw RuntimeError(what + ": its data: URI is not valid base64");
  out.resize(length);
  return out;
}

// doc[array][index] as an object; RuntimeError (`what`) where the file has none.
const nlohmann::json& element(const nlohmann::json& doc, const char* array,
                              const nlohmann::json& index, const std::string& what) {
  if (!index.is_number_integer() || !doc.contains(array) || !doc[array].is_array() ||
      index.get<int64_t>() < 0 || size_t(index.get<int64_t>()) >= doc[array].size() ||
      !doc[array][size_t(index.get<int64_t>())].is_object())
    throw RuntimeError(what + ": " + array + " " + index.dump() + " is not in the file");
  return doc[array][size_t(index.get<int64_t>())];
}

// The bytes of buffer view `index` of the glTF file `path` (`bin`: a .glb's
// binary chunk): from that chunk, a data: URI or a file beside the scene.
std::string buffer_view_bytes(const std::filesystem::path& path, const nlohmann::json& doc,
                              const std::string& bin, const nlohmann::json& index,
                              const std::string& what) {
  const auto& view = element(doc, "bufferViews", index, what);
  const auto& buffer =
      element(doc, "buffers", view.contains("buffer") ? view["buffer"] : nlohmann::json(), what);
  std::string owned;
  const std::string* data = &bin;  // the .glb's binary chunk
  if (!buffer.contains("uri")) {
  } else if (!buffer["uri"].is_string()) {
    throw RuntimeError(what + ": its buffer's uri is not a string");
  } else if (const std::string uri = buffer["uri"].get<std::string>();
             uri.compare(0, 5, "data:") == 0) {
    data = &(owned = data_uri_bytes(uri, what));
  } else {
    data = &(owned = read_file_bytes(path.parent_path() / uri));
  }
  auto size_of = [&](const char* key, bool required) -> uint64_t {
    if (!view.contains(key) && !required) return 0;
    if (!view.contains(key) || !view[key].is_number_unsigned())
      throw RuntimeError(what + ": its buffer view's " + key + " is not a count of bytes");
    return view[key].get<uint64_t>();
  };
  const uint64_t offset = size_of("byteOffset", false), length = size_of("byteLength", true);
  if (offset > data->size() || length > data->size() - offset)
    throw RuntimeError(what + ": its buffer view lies outside its buffer");
  return data->substr(size_t(offset), size_t(length));
}

// The floats of accessor `index` (componentType FLOAT; the view's
// byteStride where it has one), element by element.
std::vector<float> accessor_floats(const std::filesystem::path& path, const nlohmann::json& doc,
                                   const std::string& bin, const nlohmann::json& index,
                                   const std::string& what) {
  const auto& acc = element(doc, "accessors", index, what);
  static const std::map<std::string, size_t> kWidths = {
      {"SCALAR", 1}, {"VEC2", 2}, {"VEC3", 3}, {"VEC4", 4}};
  const auto type = kWidths.find(acc.value("type", std::string()));
  if (acc.value("componentType", 0) != 5126 || type == kWidths.end() ||
      !acc.contains("bufferView") || !acc.value("count", nlohmann::json()).is_number_unsigned())
    throw RuntimeError(what + ": accessor " + index.dump() +
                       " is not a FLOAT SCALAR or VECn in a buffer view");
  const size_t width = type->second, count = acc["count"].get<size_t>();
  const std::string bytes = buffer_view_bytes(path, doc, bin, acc["bufferView"], what);
  const auto& view = doc["bufferViews"][acc["bufferView"].get<size_t>()];
  const size_t offset = acc.value("byteOffset", size_t(0));
  const size_t stride = view.value("byteStride", width * 4);
  if (count > 0 && (stride < width * 4 || offset + (count - 1) * stride + width * 4 > bytes.size()))
    throw RuntimeError(what + ": accessor " + index.dump() + " reaches beyond its buffer view");
  std::vector<float> out(count * width);
  for (size_t i = 0; i < count; ++i)
    std::memcpy(&out[i * width], bytes.data() + offset + i * stride, width * 4);
  return out;
}

}  // namespace

std::string read_gltf_image(const std::filesystem::path& path, int image) {
  const std::string what = path.string() + ": image " + std::to_string(image);
  std::string json_text, bin;
  if (!split_gltf(read_file_bytes(path), &json_text, &bin))
    throw RuntimeError(what + ": the .glb's JSON chunk is cut short");
  const auto doc = nlohmann::json::parse(json_text, nullptr, /*allow_exceptions=*/false);
  const auto& img = element(doc, "images", image, what);
  if (img.contains("uri") && img["uri"].is_string())
    return data_uri_bytes(img["uri"].get<std::string>(), what);
  if (!img.contains("bufferView")) throw RuntimeError(what + ": neither a uri nor a bufferView");
  return buffer_view_bytes(path, doc, bin, img["bufferView"], what);
}

namespace {

// The animation channels that move named nodes (glTF 2.0, 3.11).
// A CUBICSPLINE sampler's output is read here (assimp 5.2 keeps only its
// values): in-tangent, value and out-tangent of each key (glTF Appendix C).
std::vector<GltfInfo::AnimatedPath> animated_paths(const std::filesystem::path& path,
                                                   const nlohmann::json& doc,
                                                   const std::string& bin) {
  std::vector<GltfInfo::AnimatedPath> out;
  if (!doc.contains("animations") || !doc["animations"].is_array() || !doc.contains("nodes") ||
      !doc["nodes"].is_array())
    return out;
  const auto& nodes = doc["nodes"];
  for (size_t a = 0; a < doc["animations"].size(); ++a) {
    const auto& anim = doc["animations"][a];
    if (!anim.is_object() || !anim.contains("channels") || !anim["channels"].is_array() ||
        !anim.contains("samplers") || !anim["samplers"].is_array())
      continue;
    const auto& samplers = anim["samplers"];
    for (const auto& ch : anim["channels"]) {
      if (!ch.is_object() || !ch.contains("target") || !ch["target"].is_object()) continue;
      const auto& target = ch["target"];
      const auto s = ch.value("sampler", nlohmann::json()),
                 n = target.value("node", nlohmann::json());
      if (!s.is_number_unsigned() || s.get<size_t>() >= samplers.size() ||
          !n.is_number_unsigned() || n.get<size_t>() >= nodes.size())
        continue;
      const auto& sampler = samplers[s.get<size_t>()];
      const auto& node = nodes[n.get<size_t>()];
      const std::string mode = sampler.is_object() && sampler.contains("interpolation") &&
                                       sampler["interpolation"].is_string()
                                   ? sampler["interpolation"].get<std::string>()
                                   : "LINEAR";
      if (!node.is_object() || !node.contains("name") || !node["name"].is_string() ||
          !target.contains("path") || !target["path"].is_string())
        continue;
      GltfInfo::AnimatedPath ap{
          a, node["name"].get<std::string>(), target["path"].get<std::string>(), mode, {}};
      if (mode == "CUBICSPLINE" && sampler.contains("output")) {
        try {
          ap.cubic = accessor_floats(path, doc, bin, sampler["output"],
                                     path.string() + ": animation " + std::to_string(a));
        } catch (const RuntimeError& e) {
          spdlog::warn("{}; its keys are interpolated linearly", e.what());
        }
      }
      out.push_back(std::move(ap));
    }
  }
  return out;
}

}  // namespace

GltfInfo read_gltf_info(const std::filesystem::path& path) {
  std::string json_text, bin, bytes;
  try {
    bytes = read_file_bytes(path);
  } catch (const RuntimeError&) {
    return {};  // the loader says why it cannot read the file
  }
  if (!split_gltf(bytes, &json_text, &bin)) return {};
  GltfInfo out;
  auto doc = nlohmann::json::parse(json_text, nullptr, /*allow_exceptions=*/false);
  if (!doc.is_object()) return out;  // assimp gives the reason
  out.extensions_used = string_list(doc, "extensionsUsed");
  if (doc.contains("asset") && doc["asset"].is_object() && doc["asset"].contains("generator") &&
      doc["asset"]["generator"].is_string())
    out.generator = doc["asset"]["generator"].get<std::string>();
  out.extensions_required = string_list(doc, "extensionsRequired");
  if (doc.contains("meshes") && doc["meshes"].is_array()) {
    size_t index = 0;
    for (const auto& mesh : doc["meshes"]) {
      bool unmaterialled = false;
      if (mesh.is_object() && mesh.contains("primitives") && mesh["primitives"].is_array())
        for (const auto& prim : mesh["primitives"]) {
          if (!prim.is_object()) continue;
          if (prim.contains("attributes") && prim["attributes"].is_object())
            out.vertex_colors |= prim["attributes"].contains("COLOR_0");
          unmaterialled |= !prim.contains("material");
        }
      if (unmaterialled)
        out.meshes_without_material.push_back(mesh.is_object() && mesh.contains("name") &&
                                                      mesh["name"].is_string()
                                                  ? mesh["name"].get<std::string>()
                                                  : "mesh " + std::to_string(index));
      ++index;
    }
  }
  out.textures = texture_refs(doc);
  out.animated_paths = animated_paths(path, doc, bin);
  if (doc.contains("nodes") && doc["nodes"].is_array() && doc.contains("cameras") &&
      doc["cameras"].is_array()) {
    const auto& cameras = doc["cameras"];
    for (const auto& node : doc["nodes"]) {
      if (!node.is_object() || !node.contains("camera") || !node["camera"].is_number_unsigned())
        continue;
      const size_t c = node["camera"].get<size_t>();
      if (c >= cameras.size() || !cameras[c].is_object()) continue;
      GltfInfo::CameraNode cn;
      cn.orthographic = !cameras[c].contains("perspective") &&
                        cameras[c].contains("orthographic") &&
                        cameras[c]["orthographic"].is_object();
      const char* type = cn.orthographic ? "orthographic" : "perspective";
      if (!cameras[c].contains(type) || !cameras[c][type].is_object()) continue;
      const auto& p = cameras[c][type];
      cn.node =
          node.contains("name") && node["name"].is_string() ? node["name"].get<std::string>() : "";
      if (p.contains("znear") && p["znear"].is_number()) cn.znear = p["znear"].get<double>();
      if (p.contains("zfar") && p["zfar"].is_number()) cn.zfar = p["zfar"].get<double>();
      if (p.contains("xmag") && p["xmag"].is_number()) cn.xmag = p["xmag"].get<double>();
      if (p.contains("ymag") && p["ymag"].is_number()) cn.ymag = p["ymag"].get<double>();
      out.camera_nodes.push_back(cn);
    }
  }
  if (!doc.contains("materials") || !doc["materials"].is_array()) return out;
  for (const auto& m : doc["materials"]) {
    GltfMaterialInfo info;
    if (!m.is_object()) {
      out.materials.push_back(info);
      continue;
    }
    // The material's extension `name` as an object, or null.
    auto extension = [&m](const char* name) -> const nlohmann::json* {
      if (!m.contains("extensions") || !m["extensions"].is_object() ||
          !m["extensions"].contains(name) || !m["extensions"][name].is_object())
        return nullptr;
      return &m["extensions"][name];
    };
    if (const auto* ext = extension("KHR_materials_emissive_strength"))
      info.emissive_strength = number_or(*ext, "emissiveStrength", 1.0f);
    if (m.contains("extensions") && m["extensions"].is_object() &&
        m["extensions"].contains("KHR_materials_ior")) {
      info.ior_present = true;
      if (const auto* ext = extension("KHR_materials_ior")) read_number(*ext, "ior", &info.ior);
    }
    if (const auto* ext = extension("KHR_materials_specular")) {
      read_number(*ext, "specularFactor", &info.specular_factor);
      read_color(*ext, "specularColorFactor", info.specular_color);
      if (ext->contains("specularTexture"))
        info.specular_tex = read_texture_info((*ext)["specularTexture"]);
      if (ext->contains("specularColorTexture"))
        info.specular_color_tex = read_texture_info((*ext)["specularColorTexture"]);
    }
    if (const auto* ext = extension("KHR_materials_transmission")) {
      read_number(*ext, "transmissionFactor", &info.transmission);
      if (ext->contains("transmissionTexture"))
        info.transmission_tex = read_texture_info((*ext)["transmissionTexture"]);
    }
    if (const auto* ext = extension("KHR_materials_clearcoat")) {
      read_number(*ext, "clearcoatFactor", &info.clearcoat);
      read_number(*ext, "clearcoatRoughnessFactor", &info.clearcoat_roughness);
      if (ext->contains("clearcoatTexture"))
        info.clearcoat_tex = read_texture_info((*ext)["clearcoatTexture"]);
      if (ext->contains("clearcoatRoughnessTexture"))
        info.clearcoat_rough_tex = read_texture_info((*ext)["clearcoatRoughnessTexture"]);
      if (ext->contains("clearcoatNormalTexture")) {
        info.clearcoat_normal_tex = read_texture_info((*ext)["clearcoatNormalTexture"]);
        info.clearcoat_normal_scale = number_or((*ext)["clearcoatNormalTexture"], "scale", 1.0f);
      }
    }
    if (const auto* ext = extension("KHR_materials_sheen")) {
      read_color(*ext, "sheenColorFactor", info.sheen_color);
      read_number(*ext, "sheenRoughnessFactor", &info.sheen_roughness);
      if (ext->contains("sheenColorTexture"))
        info.sheen_color_tex = read_texture_info((*ext)["sheenColorTexture"]);
      if (ext->contains("sheenRoughnessTexture"))
        info.sheen_rough_tex = read_texture_info((*ext)["sheenRoughnessTexture"]);
    }
    if (const auto* ext = extension("KHR_materials_volume")) {
      read_number(*ext, "attenuationDistance", &info.attenuation_distance);
      read_color(*ext, "attenuationColor", info.attenuation_color);
    }
    if (m.contains("pbrMetallicRoughness") && m["pbrMetallicRoughness"].is_object()) {
      const auto& pbr = m["pbrMetallicRoughness"];
      if (pbr.contains("baseColorTexture"))
        info.base_color = read_texture_info(pbr["baseColorTexture"]);
      if (pbr.contains("metallicRoughnessTexture"))
        info.metal_rough = read_texture_info(pbr["metallicRoughnessTexture"]);
    }
    if (m.contains("emissiveTexture")) info.emission = read_texture_info(m["emissiveTexture"]);
    if (m.contains("normalTexture")) {
      info.normal = read_texture_info(m["normalTexture"]);
      info.normal_scale = number_or(m["normalTexture"], "scale", 1.0f);
    }
    const std::string mode = m.contains("alphaMode") && m["alphaMode"].is_string()
                                 ? m["alphaMode"].get<std::string>()
                                 : "OPAQUE";
    info.mask = mode == "MASK";
    info.blend = mode == "BLEND";
    info.alpha_cutoff = number_or(m, "alphaCutoff", 0.5f);
    if (m.contains("pbrMetallicRoughness") && m["pbrMetallicRoughness"].is_object()) {
      const auto& f = m["pbrMetallicRoughness"];
      if (f.contains("baseColorFactor") && f["baseColorFactor"].is_array() &&
          f["baseColorFactor"].size() == 4 && f["baseColorFactor"][3].is_number())
        info.base_alpha = f["baseColorFactor"][3].get<float>();
    }
    info.name = m.contains("name") && m["name"].is_string() ? m["name"].get<std::string>() : "";
    out.materials.push_back(std::move(info));
  }
  return out;
}

namespace {

// KHR_materials_specular's factors (schema: specularFactor in [0, 1],
// specularColorFactor >= 0, above 1 allowed: F0 is clamped to 1); a value
// outside them is named in a warning and the extension's default used.
void read_specular_layer(const std::filesystem::path& path, const std::string& which,
                         const GltfMaterialInfo& g, Material* m) {
  if (std::isfinite(g.specular_factor) && g.specular_factor >= 0 && g.specular_factor <= 1) {
    m->specular = float(g.specular_factor);
  } else {
    spdlog::warn("{}: {}: KHR_materials_specular specularFactor {} is outside [0, 1]; using 1",
                 path.string(), which, g.specular_factor);
  }
  const double* c = g.specular_color;
  const bool color_ok = std::isfinite(c[0]) && std::isfinite(c[1]) && std::isfinite(c[2]) &&
                        c[0] >= 0 && c[1] >= 0 && c[2] >= 0 && c[0] <= 1e6 && c[1] <= 1e6 &&
                        c[2] <= 1e6;
  if (color_ok) {
    m->specular_color = Vec3(float(c[0]), float(c[1]), float(c[2]));
  } else {
    spdlog::warn(
        "{}: {}: KHR_materials_specular specularColorFactor [{}, {}, {}] is not three numbers in "
        "[0, 1e6]; using [1, 1, 1]",
        path.string(), which, c[0], c[1], c[2]);
  }
}
// KHR_materials_transmission's factor (schema: [0, 1]); a value outside
// is named in a warning and the extension's default 0 used. Its texture is
// the loader's (scene_data.cpp).
void read_transmission(const std::filesystem::path& path, const std::string& which,
                       const GltfMaterialInfo& g, Material* m) {
  if (std::isfinite(g.transmission) && g.transmission >= 0 && g.transmission <= 1) {
    m->transmission = float(g.transmission);
  } else {
    spdlog::warn(
        "{}: {}: KHR_materials_transmission transmissionFactor {} is outside [0, 1]; using 0",
        path.string(), which, g.transmission);
  }
}
// KHR_materials_volume's attenuation (schema: attenuationDistance > 0,
// attenuationColor in [0, 1]): sigma_a = -ln(c) / d per channel; a value
// outside is named in a warning and the extension's default (no
// absorption) used. Only transmissive materials let light inside.
void read_volume(const std::filesystem::path& path, const std::string& which,
                 const GltfMaterialInfo& g, Material* m) {
  const double d = g.attenuation_distance;
  const double* c = g.attenuation_color;
  if (!(d > 0)) {  // NaN too
    spdlog::warn(
        "{}: {}: KHR_materials_volume attenuationDistance {} is not above 0; no absorption",
        path.string(), which, d);
    return;
  }
  for (int k = 0; k < 3; ++k)
    if (!(c[k] >= 0 && c[k] <= 1)) {
      spdlog::warn(
          "{}: {}: KHR_materials_volume attenuationColor [{}, {}, {}] is not three "
          "numbers in [0, 1]; no absorption",
          path.string(), which, c[0], c[1], c[2]);
      return;
    }
  if (std::isinf(d)) return;  // the default: clear
  // A channel of 0 absorbs everything: a large finite coefficient keeps
  // exp(-sigma t) a plain 0 without infinities.
  auto sigma = [&](double ck) { return float(std::min(-std::log(std::max(ck, 1e-30)) / d, 1e30)); };
  m->attenuation = Vec3(sigma(c[0]), sigma(c[1]), sigma(c[2]));
}
// KHR_materials_clearcoat's factors (schema: both in [0, 1]); a value
// outside is named in a warning and the extension's default 0 used. Its
// textures are the loader's (scene_data.cpp), but for the coat's own normal
// map, which is named in a warning and not applied.
void read_clearcoat(const std::filesystem::path& path, const std::string& which,
                    const GltfMaterialInfo& g, Material* m) {
  auto factor = [&](double v, const char* key, float* out) {
    if (std::isfinite(v) && v >= 0 && v <= 1) {
      *out = float(v);
    } else {
      spdlog::warn("{}: {}: KHR_materials_clearcoat {} {} is outside [0, 1]; using 0",
                   path.string(), which, key, v);
    }
  };
  factor(g.clearcoat, "clearcoatFactor", &m->clearcoat);
  factor(g.clearcoat_roughness, "clearcoatRoughnessFactor", &m->clearcoat_roughness);
}

// KHR_materials_sheen's factors (schema: each in [0, 1]); a value outside
// is named in a warning and the extension's default (black, 0) used.
void read_sheen(const std::filesystem::path& path, const std::string& which,
                const GltfMaterialInfo& g, Material* m) {
  auto in_range = [](double v) { return std::isfinite(v) && v >= 0 && v <= 1; };
  const double* c = g.sheen_color;
  if (in_range(c[0]) && in_range(c[1]) && in_range(c[2])) {
    m->sheen_color = Vec3(float(c[0]), float(c[1]), float(c[2]));
  } else {
    spdlog::warn(
        "{}: {}: KHR_materials_sheen sheenColorFactor [{}, {}, {}] is outside [0, 1]; "
        "using black (no sheen)",
        path.string(), which, c[0], c[1], c[2]);
  }
  if (in_range(g.sheen_roughness)) {
    m->sheen_roughness = float(g.sheen_roughness);
  } else {
    spdlog::warn("{}: {}: KHR_materials_sheen sheenRoughnessFactor {} is outside [0, 1]; using 0",
                 path.string(), which, g.sheen_roughness);
  }
}

}  // namespace

void apply_material_extensions(const std::filesystem::path& path, const GltfMaterialInfo& g,
                               unsigned index, Material* m) {
  const std::string which = "material " + std::to_string(index) + " (\"" + m->name + "\")";
  read_specular_layer(path, which, g, m);
  read_transmission(path, which, g, m);
  read_volume(path, which, g, m);
  read_clearcoat(path, which, g, m);
  read_sheen(path, which, g, m);
}

// glTF 3.12: a required extension the loader does not implement means the
// asset cannot be rendered correctly, so it is refused; one that is only
// used is named in one warning, so nothing is dropped silently.
void check_extensions(const std::filesystem::path& path, const GltfInfo& info) {
  std::string required, used;
  for (const std::string& e : info.extensions_required)
    if (!implemented_extensions().count(e)) required += (required.empty() ? "" : ", ") + e;
  if (!required.empty())
    throw SpecError(
        FileLoc{path.string()}, "scene",
        "extensionsRequired lists " + required +
            ", which dofarm does not implement (it implements " +
            "KHR_lights_punctual, KHR_materials_clearcoat, KHR_materials_emissive_strength, "
            "KHR_materials_ior, KHR_materials_sheen, " +
            "KHR_materials_specular, KHR_materials_transmission, KHR_materials_volume, "
            "KHR_texture_transform)");
  for (const std::string& e : info.extensions_used)
    if (!implemented_extensions().count(e)) used += (used.empty() ? "" : ", ") + e;
  if (!used.empty())
    spdlog::warn("{}: dofarm ignores the glTF extensions {} (the scene renders without them)",
                 path.string(), used);
  // glTF multiplies the base colour by COLOR_0; Blender's exporter writes
  // it for every mesh with a colour attribute, which Blender's own render
  // uses only where a material reads it, so dofarm does not apply it.
  if (info.vertex_colors)
    spdlog::warn("{}: vertex colours (COLOR_0) are not applied to the base colour", path.string());
  // glTF 3.9: a primitive without a material gets the default one, white
  // metal of roughness 1, which dofarm renders as the specification says;
  // Blender shows an object without a material in its grey default surface
  // and exports it without one.
  if (!info.meshes_without_material.empty()) {
    spdlog::warn(
        "{}: {} without a material: rendered with glTF's default material (base colour 1, "
        "metallic 1, roughness 1), not Blender's grey default surface; give {} a material",
        path.string(), quoted_list(info.meshes_without_material),
        info.meshes_without_material.size() == 1 ? "it" : "them");
  }
}

}  // namespace dofarm::render
