// What the glTF loader tests share: a scratch folder, a log capture, and a
// one-quad glTF document to edit and write as .gltf (buffer in a data: URI)
// or .glb, with small encoders (base64, PNG through stb_image_write), and
// checks of what loading it gives (warnings, hits on the quad, a material
// extension as read).
#pragma once

#include <gtest/gtest.h>
#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

#include "common/error.h"
#include "common/exr_io.h"
#include "worker/render/camera.h"
#include "worker/render/environment.h"
#include "worker/render/scene.h"
#include "worker/render/scene_data.h"

// Static, so each test file's stb_image_write cannot clash with another's.
#define STB_IMAGE_WRITE_STATIC
#define STB_IMAGE_WRITE_IMPLEMENTATION
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-function"
#include <stb_image_write.h>
#pragma GCC diagnostic pop

namespace dofarm::render::gltf_fixture {

inline void expect_near3(Vec3 a, Vec3 b, float tol) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

using Json = nlohmann::json;

// A scratch folder per test, removed at the end.
struct TempDir {
  std::filesystem::path path;
  explicit TempDir(const std::string& name)
      : path(std::filesystem::temp_directory_path() / ("dofarm_test_gltf_" + name)) {
    std::filesystem::remove_all(path);
    std::filesystem::create_directories(path);
  }
  ~TempDir() { std::filesystem::remove_all(path); }
};

// Captures what spdlog logs from its construction until lines() is called,
// which puts the previous logger back.
class LogCapture {
 public:
  LogCapture()
      : sink_(std::make_shared<spdlog::sinks::ringbuffer_sink_mt>(16)),
        previous_(spdlog::default_logger()) {
    spdlog::set_default_logger(std::make_shared<spdlog::logger>("capture", sink_));
  }
  ~LogCapture() { spdlog::set_default_logger(previous_); }
  std::vector<std::string> lines() {
    spdlog::set_default_logger(previous_);
    return sink_->last_formatted();
  }

 private:
  std::shared_ptr<spdlog::sinks::ringbuffer_sink_mt> sink_;
  std::shared_ptr<spdlog::logger> previous_;
};

inline void write_bytes(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

inline std::string base64(const std::string& in) {
  static const char* table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8) | uint8_t(in[i + 2]);
    for (int k = 3; k >= 0; --k) out += table[(v >> (6 * k)) & 63];
  }
  if (i + 1 == in.size()) {
    uint32_t v = uint8_t(in[i]) << 16;
    out += std::string{table[v >> 18], table[(v >> 12) & 63], '=', '='};
  } else if (i + 2 == in.size()) {
    uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8);
    out += std::string{table[v >> 18], table[(v >> 12) & 63], table[(v >> 6) & 63], '='};
  }
  return out;
}

// A w x h PNG of `channels` 8-bit channels (row-major texels), encoded in
// memory.
inline std::string encode_png(const unsigned char* px, int w, int h, int channels) {
  std::string out;
  stbi_write_png_to_func(
      [](void* ctx, void* data, int size) {
        static_cast<std::string*>(ctx)->append(static_cast<const char*>(data), size_t(size));
      },
      &out, w, h, channels, px, w * channels);
  return out;
}

// A 3x2 RGB PNG with distinct texels, encoded in memory.
inline std::string test_png() {
  const unsigned char px[] = {255, 0,   0,   0,  255, 0, 0,   0,   255,
                              10,  128, 250, 77, 33,  1, 200, 200, 9};
  return encode_png(px, 3, 2, 3);
}

inline std::string floats_bytes(std::initializer_list<float> v) {
  std::string out(v.size() * 4, '\0');
  std::memcpy(out.data(), std::data(v), out.size());
  return out;
}

// A unit quad in the xz plane (facing +y) with uvs, as a glTF document and
// its binary buffer (positions, uvs, uint16 indices), material 0.
struct GltfQuad {
  Json doc;
  std::string bin;
};
inline GltfQuad gltf_quad() {
  GltfQuad q;
  q.bin = floats_bytes({0, 0, 0, 0, 0, 1, 1, 0, 1, 1, 0, 0});  // 48 bytes
  q.bin += floats_bytes({0, 0, 0, 1, 1, 1, 1, 0});             // 32 bytes
  const uint16_t idx[6] = {0, 1, 2, 0, 2, 3};
  q.bin.append(reinterpret_cast<const char*>(idx), sizeof idx);  // 12 bytes
  q.doc = Json::parse(R"({
    "asset": {"version": "2.0"},
    "scene": 0, "scenes": [{"nodes": [0]}],
    "nodes": [{"mesh": 0, "name": "quad"}],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                                "indices": 2, "material": 0}]}],
    "materials": [{"name": "mat", "pbrMetallicRoughness": {"metallicFactor": 0}}],
    "accessors": [
      {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
       "min": [0, 0, 0], "max": [1, 0, 1]},
      {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
      {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    "bufferViews": [
      {"buffer": 0, "byteOffset": 0, "byteLength": 48},
      {"buffer": 0, "byteOffset": 48, "byteLength": 32},
      {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
    "buffers": [{"byteLength": 92}]
  })");
  return q;
}

// Gives the quad's four vertices the attribute `name` with the values
// `per_vertex` (4 x 2, 3 or 4 floats, vertex by vertex), in a new accessor
// and buffer view.
inline void add_vertex_attribute(GltfQuad* q, const char* name,
                                 const std::vector<float>& per_vertex) {
  const size_t at = q->bin.size();
  q->bin.append(reinterpret_cast<const char*>(per_vertex.data()), per_vertex.size() * 4);
  const size_t view = q->doc["bufferViews"].size();
  q->doc["accessors"].push_back({{"bufferView", view},
                                 {"componentType", 5126},
                                 {"count", 4},
                                 {"type", "VEC" + std::to_string(per_vertex.size() / 4)}});
  q->doc["bufferViews"].push_back(
      {{"buffer", 0}, {"byteOffset", at}, {"byteLength", 4 * per_vertex.size()}});
  q->doc["meshes"][0]["primitives"][0]["attributes"][name] = q->doc["accessors"].size() - 1;
}

// Gives every vertex of the quad the attribute `name` with the value `v`
// (3 or 4 floats).
inline void add_attribute(GltfQuad* q, const char* name, std::initializer_list<float> v) {
  std::vector<float> all;
  for (int k = 0; k < 4; ++k) all.insert(all.end(), v.begin(), v.end());
  add_vertex_attribute(q, name, all);
}

// Writes `q` as a .gltf whose buffer is a data: URI.
inline void write_gltf(const std::filesystem::path& p, GltfQuad q) {
  q.doc["buffers"][0]["byteLength"] = q.bin.size();
  q.doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64(q.bin);
  write_bytes(p, q.doc.dump());
}

// Writes `q` as a .glb: header, JSON chunk, BIN chunk (glTF 2.0, 4.4).
inline void write_glb(const std::filesystem::path& p, GltfQuad q) {
  while (q.bin.size() % 4) q.bin += '\0';
  q.doc["buffers"][0]["byteLength"] = q.bin.size();
  std::string json = q.doc.dump();
  while (json.size() % 4) json += ' ';
  auto u32 = [](uint32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); };
  std::string out = "glTF" + u32(2) + u32(uint32_t(12 + 8 + json.size() + 8 + q.bin.size()));
  out += u32(uint32_t(json.size())) + "JSON" + json;
  out += u32(uint32_t(q.bin.size())) + "BIN" + std::string(1, '\0') + q.bin;
  write_bytes(p, out);
}

inline void use_base_color_image(GltfQuad* q, const Json& image) {
  q->doc["images"] = Json::array({image});
  q->doc["textures"] = Json::parse(R"([{"source": 0}])");
  q->doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 0}};
}

inline void expect_same_texture(const Texture& a, const Texture& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_EQ(a.rgb, b.rgb);  // bit for bit
}

// The log holds exactly one line per entry of `expected`, in order, each
// holding every fragment of its entry.
inline void expect_warnings(const std::vector<std::string>& lines,
                            const std::vector<std::vector<std::string>>& expected) {
  ASSERT_EQ(lines.size(), expected.size());
  for (size_t i = 0; i < lines.size(); ++i)
    for (const std::string& fragment : expected[i])
      EXPECT_NE(lines[i].find(fragment), std::string::npos) << lines[i];
}

// What Scene::intersect gives where rays straight down meet the quad at
// u = 0.25 and u = 0.75 (the left and right texel of a 2 x 1 image).
inline std::pair<SurfaceHit, SurfaceHit> quad_hits(const SceneData& d) {
  Scene scene(d, std::make_unique<Environment>(Vec3(1.0f)));
  auto at = [&](float x) {
    SurfaceHit hit;
    EXPECT_TRUE(scene.intersect(Ray{Vec3(x, 1.0f, 0.5f), Vec3(0, -1, 0)}, &hit));
    return hit;
  };
  return {at(0.25f), at(0.75f)};
}

// A material extension that is read is never named in the "ignores" warning.
inline void expect_extension_read(const std::vector<std::string>& lines) {
  for (const std::string& l : lines)
    EXPECT_EQ(l.find("ignores the glTF extensions"), std::string::npos) << l;
}

// The quad's material, named `name`, with the material extension `ext_name`
// holding `ext` (none for null), as load_scene_data() reads it.
inline Material material_with_extension(const std::filesystem::path& dir, const char* name,
                                        const char* ext_name, const Json& ext) {
  GltfQuad q = gltf_quad();
  q.doc["materials"][0]["name"] = name;
  if (!ext.is_null()) {
    q.doc["materials"][0]["extensions"] = {{ext_name, ext}};
    q.doc["extensionsUsed"] = {ext_name};
  }
  write_gltf(dir / (std::string(name) + ".gltf"), q);
  SceneData s = load_scene_data(dir / (std::string(name) + ".gltf"));
  EXPECT_EQ(s.triangle_count(), 2u);
  const Material m = s.materials[s.tri_material[0]];
  EXPECT_EQ(m.name, name);
  return m;
}

}  // namespace dofarm::render::gltf_fixture
