// glTF coverage (docs/renderer.md, "glTF coverage"): textures embedded in a
// .glb or a data: URI, KHR_texture_transform, KHR_lights_punctual in
// Blender's units, the extension warning and refusal, and the load errors of
// empty scenes and out-of-bound emission. The files are written by the tests,
// except one .glb exported by Blender (tests/data/blender/).
#include <gtest/gtest.h>
#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "common/error.h"
#include "common/exr_io.h"
#include "worker/render/camera.h"
#include "worker/render/environment.h"
#include "worker/render/scene.h"
#include "worker/render/scene_data.h"

// Static, so this test's stb_image_write cannot clash with another file's.
#define STB_IMAGE_WRITE_STATIC
#define STB_IMAGE_WRITE_IMPLEMENTATION
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-function"
#include <stb_image_write.h>
#pragma GCC diagnostic pop

namespace dofarm::render {
namespace {

void expect_near3(Vec3 a, Vec3 b, float tol) {
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

void write_bytes(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

std::string base64(const std::string& in) {
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

// A 3x2 RGB PNG with distinct texels, encoded in memory.
std::string test_png() {
  const unsigned char px[] = {255, 0,   0,   0,  255, 0, 0,   0,   255,
                              10,  128, 250, 77, 33,  1, 200, 200, 9};
  std::string out;
  stbi_write_png_to_func(
      [](void* ctx, void* data, int size) {
        static_cast<std::string*>(ctx)->append(static_cast<const char*>(data), size_t(size));
      },
      &out, 3, 2, 3, px, 3 * 3);
  return out;
}

std::string floats_bytes(std::initializer_list<float> v) {
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
GltfQuad gltf_quad() {
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

// Gives every vertex of the quad the attribute `name` with the value `v`
// (3 or 4 floats), in a new accessor and buffer view.
void add_attribute(GltfQuad* q, const char* name, std::initializer_list<float> v) {
  const size_t at = q->bin.size();
  for (int k = 0; k < 4; ++k) q->bin += floats_bytes(v);
  const size_t view = q->doc["bufferViews"].size();
  q->doc["accessors"].push_back({{"bufferView", view},
                                 {"componentType", 5126},
                                 {"count", 4},
                                 {"type", v.size() == 4 ? "VEC4" : "VEC3"}});
  q->doc["bufferViews"].push_back(
      {{"buffer", 0}, {"byteOffset", at}, {"byteLength", 16 * v.size()}});
  q->doc["meshes"][0]["primitives"][0]["attributes"][name] = q->doc["accessors"].size() - 1;
}

// Writes `q` as a .gltf whose buffer is a data: URI.
void write_gltf(const std::filesystem::path& p, GltfQuad q) {
  q.doc["buffers"][0]["byteLength"] = q.bin.size();
  q.doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64(q.bin);
  write_bytes(p, q.doc.dump());
}

// Writes `q` as a .glb: header, JSON chunk, BIN chunk (glTF 2.0, 4.4).
void write_glb(const std::filesystem::path& p, GltfQuad q) {
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

void use_base_color_image(GltfQuad* q, const Json& image) {
  q->doc["images"] = Json::array({image});
  q->doc["textures"] = Json::parse(R"([{"source": 0}])");
  q->doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 0}};
}

void expect_same_texture(const Texture& a, const Texture& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_EQ(a.rgb, b.rgb);  // bit for bit
}

TEST(GltfEmbeddedTextures, GlbAndDataUriLoadLikeTheImageBesideTheScene) {
  TempDir dir("embedded");
  const std::string png = test_png();
  ASSERT_FALSE(png.empty());
  write_bytes(dir.path / "tex.png", png);

  GltfQuad beside = gltf_quad();
  use_base_color_image(&beside, {{"uri", "tex.png"}});
  write_gltf(dir.path / "beside.gltf", beside);

  GltfQuad data_uri = gltf_quad();
  use_base_color_image(&data_uri, {{"uri", "data:image/png;base64," + base64(png)}});
  write_gltf(dir.path / "data_uri.gltf", data_uri);

  GltfQuad glb = gltf_quad();
  glb.doc["bufferViews"].push_back({{"buffer", 0}, {"byteOffset", 92}, {"byteLength", png.size()}});
  glb.bin += png;
  use_base_color_image(&glb, {{"bufferView", 3}, {"mimeType", "image/png"}});
  write_glb(dir.path / "scene.glb", glb);

  SceneData ref = load_scene_data(dir.path / "beside.gltf");
  ASSERT_EQ(ref.textures.size(), 1u);
  const Texture& t = ref.textures[0];
  ASSERT_EQ(t.width, 3);
  ASSERT_EQ(t.height, 2);
  // Texel (0, 1) (second row) is (10, 128, 250) in sRGB.
  EXPECT_NEAR(t.rgb[9 + 2], srgb_to_linear(250 / 255.0f), 1e-6f);
  for (const char* name : {"data_uri.gltf", "scene.glb"}) {
    SCOPED_TRACE(name);
    SceneData s = load_scene_data(dir.path / name);
    ASSERT_EQ(s.textures.size(), 1u);
    ASSERT_EQ(s.triangle_count(), 2u);
    EXPECT_EQ(s.materials[s.tri_material[0]].base_color_tex, 0);
    expect_same_texture(s.textures[0], t);
    EXPECT_EQ(s.triangle_count(), 2u);
  }
}

TEST(GltfEmbeddedTextures, CorruptEmbeddedImageNamesTheFile) {
  TempDir dir("embedded_bad");
  GltfQuad q = gltf_quad();
  use_base_color_image(&q, {{"uri", "data:image/png;base64," + base64("not a png at all")}});
  write_gltf(dir.path / "bad.gltf", q);
  try {
    load_scene_data(dir.path / "bad.gltf");
    FAIL() << "expected SpecError";
  } catch (const SpecError& e) {
    std::string what = e.what();
    EXPECT_NE(what.find("bad.gltf"), std::string::npos) << what;
    EXPECT_NE(what.find("texture"), std::string::npos) << what;
  }
}

// Blender's mapping node (Point type) maps its uv b to T + R_ccw(r) S b in
// Blender's uv convention (v up); glTF's v points down (v_gltf = 1 - v). This
// is an implementation of that, independent of KHR_texture_transform's
// matrix: the exporter's numbers must reproduce it.
Vec2 blender_mapping(Vec2 uv_gltf, Vec2 location, float rotation, Vec2 scale) {
  Vec2 b(uv_gltf.x * scale.x, (1 - uv_gltf.y) * scale.y);
  const float c = std::cos(rotation), s = std::sin(rotation);
  Vec2 r(c * b.x - s * b.y + location.x, s * b.x + c * b.y + location.y);
  return {r.x, 1 - r.y};
}

TEST(GltfTextureTransform, BlenderExportedTransformReproducesBlendersMapping) {
  // Blender 3.4 exports a Mapping node (location (0.25, 0.5), rotation 0.3,
  // scale (2, 3)) in front of an image texture as these numbers.
  TempDir dir("uv_transform");
  write_bytes(dir.path / "tex.png", test_png());
  GltfQuad q = gltf_quad();
  use_base_color_image(&q, {{"uri", "tex.png"}});
  q.doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = Json::parse(R"(
    {"KHR_texture_transform": {"offset": [-0.6365606541495139, -2.3660094568081917],
                               "rotation": 0.30000001192092896, "scale": [2, 3]}})");
  q.doc["extensionsUsed"] = {"KHR_texture_transform"};
  q.doc["extensionsRequired"] = {"KHR_texture_transform"};
  write_gltf(dir.path / "transform.gltf", q);
  SceneData s = load_scene_data(dir.path / "transform.gltf");
  ASSERT_EQ(s.triangle_count(), 2u);
  const Material& m = s.materials[s.tri_material[0]];
  ASSERT_EQ(m.base_color_tex, 0);
  const UvTransform& t = m.base_color_uv;
  EXPECT_FALSE(t.is_identity());
  EXPECT_TRUE(m.metal_rough_uv.is_identity());
  for (Vec2 uv : {Vec2(0, 0), Vec2(1, 0), Vec2(0, 1), Vec2(0.3f, 0.7f), Vec2(-2, 5)}) {
    Vec2 want = blender_mapping(uv, Vec2(0.25f, 0.5f), 0.3f, Vec2(2, 3));
    Vec2 got = t.apply(uv);
    EXPECT_NEAR(got.x, want.x, 1e-5f) << uv.x << ", " << uv.y;
    EXPECT_NEAR(got.y, want.y, 1e-5f) << uv.x << ", " << uv.y;
  }
}

TEST(GltfTextureTransform, OffsetOnlyShiftsTheLookup) {
  // The extension's own example: offset (0.5, 0) moves the texture by half.
  UvTransform t = UvTransform::from_gltf(Vec2(0.5f, 0), 0, Vec2(1, 1));
  Vec2 uv = t.apply(Vec2(0.25f, 0.75f));
  EXPECT_FLOAT_EQ(uv.x, 0.75f);
  EXPECT_FLOAT_EQ(uv.y, 0.75f);
  // Rotation by pi/2: (1, 0) -> (cos, -sin) = (0, -1) in the extension's matrix.
  Vec2 r = UvTransform::from_gltf(Vec2(0, 0), float(M_PI / 2), Vec2(1, 1)).apply(Vec2(1, 0));
  EXPECT_NEAR(r.x, 0.0f, 1e-6f);
  EXPECT_NEAR(r.y, -1.0f, 1e-6f);
}

// Blender 3.4's exporter ("Punctual Lights" ticked, lighting mode Standard)
// writes a 1000 W point lamp as 1000 / (4 pi) * 683 cd, a spot lamp as a
// point lamp of its power with outerConeAngle = spot_size / 2 and
// innerConeAngle = outer (1 - spot_blend), a 3 W/m^2 sun as 3 * 683 lux, each
// on a node turned -90 degrees about x (Blender's z-up to glTF's y-up).
const char* kBlenderLights = R"({
  "extensionsUsed": ["KHR_lights_punctual"],
  "extensionsRequired": ["KHR_lights_punctual"],
  "extensions": {"KHR_lights_punctual": {"lights": [
    {"color": [1, 1, 1], "intensity": 54351.41306588226, "type": "point", "name": "P"},
    {"color": [1, 0.5, 0.25], "intensity": 27175.70653294113,
     "spot": {"innerConeAngle": 0.39269909262657166, "outerConeAngle": 0.5235987901687622},
     "type": "spot", "name": "S"},
    {"color": [1, 1, 1], "intensity": 2049, "type": "directional", "name": "U"}]}},
  "nodes_extra": [
    {"extensions": {"KHR_lights_punctual": {"light": 0}}, "name": "Point",
     "rotation": [-0.7071068286895752, 0, 0, 0.7071068286895752], "translation": [0, 2, 0]},
    {"extensions": {"KHR_lights_punctual": {"light": 1}}, "name": "Spot",
     "rotation": [-0.7071068286895752, 0, 0, 0.7071068286895752], "translation": [1, 3, 0]},
    {"extensions": {"KHR_lights_punctual": {"light": 2}}, "name": "Sun",
     "rotation": [-0.510183572769165, 0, 0, 0.8600655794143677]}]
})";

SceneData load_with_lights(const TempDir& dir, const char* lights_json) {
  GltfQuad q = gltf_quad();
  Json extra = Json::parse(lights_json);
  for (auto& [key, value] : extra.items())
    if (key != "nodes_extra") q.doc[key] = value;
  for (const auto& node : extra["nodes_extra"]) {
    q.doc["scenes"][0]["nodes"].push_back(q.doc["nodes"].size());
    q.doc["nodes"].push_back(node);
  }
  write_gltf(dir.path / "lights.gltf", q);
  return load_scene_data(dir.path / "lights.gltf");
}

TEST(GltfLights, BlenderUnitsGiveCyclesIntensityAndIrradiance) {
  TempDir dir("lights");
  SceneData s = load_with_lights(dir, kBlenderLights);
  ASSERT_EQ(s.lights.size(), 3u);
  const PunctualLight& p = s.lights[0];
  EXPECT_EQ(p.type, PunctualLight::Type::kPoint);
  EXPECT_EQ(p.name, "Point");
  // Cycles: a P watt point lamp has radiant intensity P / (4 pi) W/sr.
  expect_near3(p.intensity, Vec3(1000.0f / (4.0f * float(M_PI))), 1e-3f);
  expect_near3(p.position, Vec3(0, 2, 0), 1e-6f);

  const PunctualLight& spot = s.lights[1];
  EXPECT_EQ(spot.type, PunctualLight::Type::kSpot);
  // 500 W, colour (1, 0.5, 0.25).
  expect_near3(spot.intensity, Vec3(1, 0.5f, 0.25f) * (500.0f / (4.0f * float(M_PI))), 1e-3f);
  expect_near3(spot.position, Vec3(1, 3, 0), 1e-6f);
  // Blender's spot shines down its -z, which is glTF's -y after the export.
  expect_near3(spot.direction, Vec3(0, -1, 0), 1e-6f);
  // spot_size 60 degrees, blend 0.25: outer 30 degrees, inner 22.5 degrees.
  EXPECT_NEAR(spot.cos_outer, std::cos(float(M_PI) / 6), 1e-6f);
  EXPECT_NEAR(spot.cos_inner, std::cos(float(M_PI) / 8), 1e-6f);

  const PunctualLight& sun = s.lights[2];
  EXPECT_EQ(sun.type, PunctualLight::Type::kDirectional);
  expect_near3(sun.intensity, Vec3(3.0f), 1e-5f);  // Cycles: strength S gives irradiance S
  // Blender sun rotated 0.5 rad about its x: its -z turns towards -y... in
  // glTF axes, rotation -(pi/2 - 0.5) about x applied to (0, 0, -1).
  const float a = -(float(M_PI) / 2 - 0.5f);
  expect_near3(sun.direction, Vec3(0, std::sin(a), -std::cos(a)), 1e-5f);
}

TEST(GltfLights, AnAnimatedLightIsPlacedAtTimeZero) {
  // The light hangs 0.5 below a parent whose static translation (0, 1, 0) is
  // animated: (0, 5, 0) at t = 0, (0, 9, 0) at t = 1. The light takes t = 0.
  TempDir dir("animated_light");
  GltfQuad q = gltf_quad();
  q.bin += floats_bytes({0, 1, 0, 5, 0, 0, 9, 0});  // times at 92, translations at 100
  q.doc["bufferViews"].push_back({{"buffer", 0}, {"byteOffset", 92}, {"byteLength", 8}});
  q.doc["bufferViews"].push_back({{"buffer", 0}, {"byteOffset", 100}, {"byteLength", 24}});
  q.doc["accessors"].push_back(Json::parse(
      R"({"bufferView": 3, "componentType": 5126, "count": 2, "type": "SCALAR",
          "min": [0], "max": [1]})"));
  q.doc["accessors"].push_back(
      Json::parse(R"({"bufferView": 4, "componentType": 5126, "count": 2, "type": "VEC3"})"));
  q.doc["nodes"].push_back(
      Json::parse(R"({"name": "rig", "translation": [0, 1, 0], "children": [2]})"));
  q.doc["nodes"].push_back(Json::parse(
      R"({"name": "lamp", "translation": [0, -0.5, 0],
          "extensions": {"KHR_lights_punctual": {"light": 0}}})"));
  q.doc["scenes"][0]["nodes"].push_back(1);
  q.doc["animations"] = Json::parse(R"([{"channels": [{"sampler": 0,
      "target": {"node": 1, "path": "translation"}}],
      "samplers": [{"input": 3, "output": 4, "interpolation": "LINEAR"}]}])");
  q.doc["extensions"]["KHR_lights_punctual"]["lights"] =
      Json::parse(R"([{"type": "point", "intensity": 683}])");
  q.doc["extensionsUsed"] = {"KHR_lights_punctual"};
  write_gltf(dir.path / "animated.gltf", q);
  SceneData s = load_scene_data(dir.path / "animated.gltf");
  ASSERT_EQ(s.lights.size(), 1u);
  expect_near3(s.lights[0].position, Vec3(0, 4.5f, 0), 1e-5f);
  expect_near3(s.lights[0].intensity, Vec3(1.0f), 1e-6f);  // 683 cd: 1 W/sr
}

TEST(GltfLights, SpotFalloffFollowsTheExtension) {
  const float ci = std::cos(0.3f), co = std::cos(0.5f);
  EXPECT_EQ(spot_falloff(1.0f, ci, co), 1.0f);
  EXPECT_EQ(spot_falloff(ci, ci, co), 1.0f);
  EXPECT_EQ(spot_falloff(co, ci, co), 0.0f);
  EXPECT_EQ(spot_falloff(std::cos(0.6f), ci, co), 0.0f);
  EXPECT_NEAR(spot_falloff(0.5f * (ci + co), ci, co), 0.25f, 1e-5f);  // halfway in cosine, squared
  // Inner = outer (a hard edge, Blender's blend 0): full inside, 0 outside.
  EXPECT_EQ(spot_falloff(std::cos(0.49f), co, co), 1.0f);
  EXPECT_EQ(spot_falloff(std::cos(0.51f), co, co), 0.0f);
}

TEST(GltfBlenderExport, LampsEmbeddedTextureAndMappingAsBlenderMeantThem) {
  // A .glb from Blender 3.4 (tests/data/blender/make_lamps_and_texture.py).
  const auto dir = std::filesystem::path(DOFARM_TEST_DATA) / "blender";
  SceneData s = load_scene_data(dir / "lamps_and_texture.glb");
  ASSERT_EQ(s.triangle_count(), 2u);
  const Material& m = s.materials[s.tri_material[0]];
  ASSERT_EQ(m.base_color_tex, 0);
  // The PNG inside the .glb decodes exactly like the file it was made from.
  RgbImage beside = load_rgb_image(dir / "tex.png", /*srgb=*/true);
  EXPECT_EQ(s.textures[0].width, beside.width);
  EXPECT_EQ(s.textures[0].height, beside.height);
  EXPECT_EQ(s.textures[0].rgb, beside.rgb);
  for (Vec2 uv : {Vec2(0, 0), Vec2(1, 1), Vec2(0.2f, 0.9f)}) {
    Vec2 want = blender_mapping(uv, Vec2(0.25f, 0.5f), 0.3f, Vec2(2, 3));
    EXPECT_NEAR(m.base_color_uv.apply(uv).x, want.x, 1e-5f);
    EXPECT_NEAR(m.base_color_uv.apply(uv).y, want.y, 1e-5f);
  }
  ASSERT_EQ(s.lights.size(), 3u);
  const float four_pi = 4.0f * float(M_PI);
  EXPECT_EQ(s.lights[0].type, PunctualLight::Type::kPoint);
  expect_near3(s.lights[0].intensity, Vec3(1000.0f / four_pi), 1e-3f);
  expect_near3(s.lights[0].position, Vec3(0, 2, 0), 1e-6f);  // Blender z up -> glTF y up
  EXPECT_EQ(s.lights[1].type, PunctualLight::Type::kSpot);
  expect_near3(s.lights[1].intensity, Vec3(500.0f / four_pi), 1e-3f);
  expect_near3(s.lights[1].position, Vec3(1, 3, 0), 1e-6f);
  expect_near3(s.lights[1].direction, Vec3(0, -1, 0), 1e-6f);
  EXPECT_NEAR(s.lights[1].cos_outer, std::cos(float(M_PI) / 6), 1e-6f);
  EXPECT_NEAR(s.lights[1].cos_inner, std::cos(0.75f * float(M_PI) / 6), 1e-6f);
  EXPECT_EQ(s.lights[2].type, PunctualLight::Type::kDirectional);
  expect_near3(s.lights[2].intensity, Vec3(3.0f), 1e-5f);
}

// --- glTF extensions and load errors -----------------------------------------

std::string load_error(const std::filesystem::path& p) {
  try {
    load_scene_data(p);
  } catch (const SpecError& e) {
    EXPECT_EQ(e.loc().file, p.string());
    return e.what();
  }
  ADD_FAILURE() << p << " loaded";
  return "";
}

TEST(GltfExtensions, RequiredButUnimplementedIsAnErrorNamingIt) {
  TempDir dir("required");
  GltfQuad q = gltf_quad();
  q.doc["extensionsUsed"] = {"KHR_materials_transmission", "KHR_texture_transform"};
  q.doc["extensionsRequired"] = {"KHR_materials_transmission"};
  write_gltf(dir.path / "required.gltf", q);
  std::string what = load_error(dir.path / "required.gltf");
  EXPECT_NE(what.find("KHR_materials_transmission"), std::string::npos) << what;
  EXPECT_NE(what.find("extensionsRequired"), std::string::npos) << what;
  EXPECT_EQ(what.find("KHR_texture_transform,"), std::string::npos) << what;
}

TEST(GltfExtensions, UsedButUnimplementedAreNamedInOneWarning) {
  TempDir dir("used");
  GltfQuad q = gltf_quad();
  q.doc["extensionsUsed"] = {"KHR_materials_sheen", "KHR_lights_punctual",
                             "KHR_materials_clearcoat"};
  write_gltf(dir.path / "used.gltf", q);
  LogCapture log;
  SceneData s = load_scene_data(dir.path / "used.gltf");
  std::vector<std::string> lines = log.lines();
  EXPECT_EQ(s.triangle_count(), 2u);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("used.gltf"), std::string::npos) << lines[0];
  EXPECT_NE(lines[0].find("KHR_materials_sheen, KHR_materials_clearcoat"), std::string::npos)
      << lines[0];
  EXPECT_EQ(lines[0].find("KHR_lights_punctual"), std::string::npos) << lines[0];
}

// COLOR_0 is not applied (Blender's exporter writes it for every mesh with a
// colour attribute; Blender renders it only where a material reads it), and
// says so once.
TEST(GltfExtensions, VertexColoursAreNamedInAWarning) {
  TempDir dir("colors");
  GltfQuad q = gltf_quad();
  add_attribute(&q, "COLOR_0", {1, 0, 0, 1});
  write_gltf(dir.path / "colors.gltf", q);
  LogCapture log;
  SceneData s = load_scene_data(dir.path / "colors.gltf");
  std::vector<std::string> lines = log.lines();
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("COLOR_0"), std::string::npos) << lines[0];
  expect_near3(s.materials[s.tri_material[0]].base_color, Vec3(1.0f), 0.0f);  // not red
}

// Normal maps and alphaMode BLEND are rendered, so a material with both
// loads without a warning.
TEST(GltfExtensions, NormalMapsAndBlendLoadWithoutWarnings) {
  TempDir dir("core_warnings");
  write_bytes(dir.path / "tex.png", test_png());
  GltfQuad q = gltf_quad();
  use_base_color_image(&q, {{"uri", "tex.png"}});
  q.doc["materials"][0]["name"] = "bumpy glass";
  q.doc["materials"][0]["normalTexture"] = {{"index", 0}};
  q.doc["materials"][0]["alphaMode"] = "BLEND";
  write_gltf(dir.path / "core.gltf", q);
  LogCapture log;
  SceneData s = load_scene_data(dir.path / "core.gltf");
  std::vector<std::string> lines = log.lines();
  EXPECT_EQ(s.triangle_count(), 2u);
  EXPECT_TRUE(lines.empty()) << lines[0];
  const Material& m = s.materials[s.tri_material[0]];
  EXPECT_TRUE(m.alpha_mask);
  EXPECT_TRUE(m.alpha_blend);
  EXPECT_GE(m.normal_tex, 0);
  EXPECT_EQ(s.tangents.size(), s.positions.size());
}

// alphaMode MASK: the cutoff, baseColorFactor's alpha and the base colour
// texture's alpha channel are read (an RGBA PNG, here 2 x 1: alpha 0 and
// 255); an opaque material loads no alpha.
TEST(GltfAlphaMask, MaskReadsCutoffFactorAndTheTexturesAlpha) {
  TempDir dir("alpha_mask");
  const unsigned char px[] = {200, 10, 10, 0, 10, 200, 10, 255};
  std::string png;
  stbi_write_png_to_func(
      [](void* ctx, void* data, int size) {
        static_cast<std::string*>(ctx)->append(static_cast<const char*>(data), size_t(size));
      },
      &png, 2, 1, 4, px, 2 * 4);
  write_bytes(dir.path / "leaf.png", png);
  GltfQuad q = gltf_quad();
  use_base_color_image(&q, {{"uri", "leaf.png"}});
  q.doc["materials"][0]["name"] = "leaf";
  q.doc["materials"][0]["alphaMode"] = "MASK";
  q.doc["materials"][0]["alphaCutoff"] = 0.25;
  q.doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = {1, 1, 1, 0.8};
  write_gltf(dir.path / "leaf.gltf", q);
  SceneData s = load_scene_data(dir.path / "leaf.gltf");
  const Material& m = s.materials[s.tri_material[0]];
  EXPECT_TRUE(m.alpha_mask);
  EXPECT_FLOAT_EQ(m.alpha_cutoff, 0.25f);
  EXPECT_FLOAT_EQ(m.base_alpha, 0.8f);
  ASSERT_GE(m.base_color_tex, 0);
  const Texture& t = s.textures[size_t(m.base_color_tex)];
  ASSERT_EQ(t.alpha.size(), 2u);
  EXPECT_EQ(t.alpha[0], 0.0f);
  EXPECT_EQ(t.alpha[1], 1.0f);
  EXPECT_NEAR(t.rgb[0], srgb_to_linear(200 / 255.0f), 1e-6f);  // colour as before

  q.doc["materials"][0].erase("alphaMode");
  write_gltf(dir.path / "opaque.gltf", q);
  SceneData o = load_scene_data(dir.path / "opaque.gltf");
  EXPECT_FALSE(o.materials[o.tri_material[0]].alpha_mask);
  EXPECT_TRUE(o.textures[size_t(o.materials[o.tri_material[0]].base_color_tex)].alpha.empty());
}

// A cut-out point is not there for any ray: closest-hit queries go on to
// the surface behind it and shadow queries pass it; the rest of the masked
// surface and unmasked surfaces are hit as before. Two unit quads, the
// masked one (alpha 0 for u < 0.5, 1 above, by a 2 x 1 texture) at y = 1
// over an opaque one at y = 0.
TEST(GltfAlphaMask, CutOutPointsLetEveryRayThrough) {
  SceneData d;
  Texture tex;
  tex.width = 2;
  tex.height = 1;
  tex.rgb.assign(6, 0.5f);
  tex.alpha = {0.0f, 1.0f};
  d.textures.push_back(tex);
  const std::vector<Vec2> uv = {{0, 0}, {0, 1}, {1, 1}, {1, 0}};
  const std::vector<uint32_t> idx = {0, 1, 2, 0, 2, 3};
  auto quad = [](float y) { return std::vector<Vec3>{{0, y, 0}, {0, y, 1}, {1, y, 1}, {1, y, 0}}; };
  Material floor, leaf;
  leaf.alpha_mask = true;
  leaf.base_color_tex = 0;
  d.add_mesh(quad(0.0f), {}, uv, idx, floor);
  d.add_mesh(quad(1.0f), {}, uv, idx, leaf);
  auto first_hit_y = [](const Scene& scene, float x) {
    SurfaceHit hit;
    if (!scene.intersect(Ray{Vec3(x, 2.0f, 0.5f), Vec3(0, -1, 0)}, &hit)) return -1.0f;
    return hit.p.y;
  };
  {
    Scene scene(d, std::make_unique<Environment>(Vec3(1.0f)));
    // Bilinear between texel centres at u = 0.25 and 0.75: alpha < 0.5 below u = 0.5.
    EXPECT_FLOAT_EQ(first_hit_y(scene, 0.1f), 0.0f);
    EXPECT_FLOAT_EQ(first_hit_y(scene, 0.4f), 0.0f);
    EXPECT_FLOAT_EQ(first_hit_y(scene, 0.6f), 1.0f);
    EXPECT_FLOAT_EQ(first_hit_y(scene, 0.9f), 1.0f);
    // Shadow rays between y = 2 and y = 0.5 (above the floor).
    EXPECT_FALSE(scene.occluded(Vec3(0.1f, 2.0f, 0.5f), Vec3(0, -1, 0), 1.5f));
    EXPECT_TRUE(scene.occluded(Vec3(0.9f, 2.0f, 0.5f), Vec3(0, -1, 0), 1.5f));
  }
  // baseColorFactor's alpha scales the texture's: at u = 0.75 (a texel
  // centre, alpha 1) 0.4 x 1 is cut at cutoff 0.5 and kept at 0.3.
  d.materials[1].base_alpha = 0.4f;
  {
    Scene scene(d, std::make_unique<Environment>(Vec3(1.0f)));
    EXPECT_FLOAT_EQ(first_hit_y(scene, 0.75f), 0.0f);
  }
  d.materials[1].alpha_cutoff = 0.3f;
  {
    Scene scene(d, std::make_unique<Environment>(Vec3(1.0f)));
    EXPECT_FLOAT_EQ(first_hit_y(scene, 0.75f), 1.0f);
    EXPECT_FLOAT_EQ(first_hit_y(scene, 0.1f), 0.0f);
  }
}

// alphaMode BLEND: a ray stops at the surface with probability alpha (the
// share of what is behind that the surface covers), decided by a hash of
// the ray, so the same ray always decides the same way. Over 4000 rays
// down onto a BLEND plane of alpha 0.3 over an opaque floor, 30% stop at the
// plane (within 4 standard deviations), and shadow rays pass as often.
TEST(GltfAlphaMask, BlendStopsAShareAlphaOfTheRays) {
  SceneData d;
  const std::vector<Vec2> uv = {{0, 0}, {0, 1}, {1, 1}, {1, 0}};
  const std::vector<uint32_t> idx = {0, 1, 2, 0, 2, 3};
  auto quad = [](float y) { return std::vector<Vec3>{{0, y, 0}, {0, y, 1}, {1, y, 1}, {1, y, 0}}; };
  Material floor, glass;
  glass.alpha_mask = glass.alpha_blend = true;
  glass.base_alpha = 0.3f;
  d.add_mesh(quad(0.0f), {}, uv, idx, floor);
  d.add_mesh(quad(1.0f), {}, uv, idx, glass);
  Scene scene(std::move(d), std::make_unique<Environment>(Vec3(1.0f)));
  const int n = 4000;
  int stopped = 0, blocked = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 o(0.05f + 0.9f * float(i % 63) / 63.0f, 2.0f, 0.05f + 0.9f * float(i / 63) / 64.0f);
    SurfaceHit hit, again;
    ASSERT_TRUE(scene.intersect(Ray{o, Vec3(0, -1, 0)}, &hit));
    ASSERT_TRUE(scene.intersect(Ray{o, Vec3(0, -1, 0)}, &again));
    EXPECT_EQ(hit.p.y, again.p.y);  // the same ray, the same decision
    stopped += hit.p.y == 1.0f ? 1 : 0;
    blocked += scene.occluded(o + Vec3(0.001f, 0, 0), Vec3(0, -1, 0), 1.5f) ? 1 : 0;
  }
  const double sigma = std::sqrt(n * 0.3 * 0.7);
  EXPECT_NEAR(stopped, 0.3 * n, 4 * sigma);
  EXPECT_NEAR(blocked, 0.3 * n, 4 * sigma);
}

// Normal-map texels for a 30-degree bend: sin and cos of 30 degrees, and a
// component in [-1, 1] as its 8-bit code; each code is within 1/255 of the
// value, so bent normals are within kTexelTolerance.
const float s30 = 0.5f, c30 = std::sqrt(3.0f) / 2.0f;
constexpr float kTexelTolerance = 6e-3f;
unsigned char q8(float x) { return static_cast<unsigned char>(std::lround((x + 1) * 127.5f)); }

std::string png_1x1(unsigned char r, unsigned char g, unsigned char b) {
  const unsigned char px[] = {r, g, b};
  std::string out;
  stbi_write_png_to_func(
      [](void* ctx, void* data, int size) {
        static_cast<std::string*>(ctx)->append(static_cast<const char*>(data), size_t(size));
      },
      &out, 1, 1, 3, px, 3);
  return out;
}

// The shading normal where a ray straight down meets the quad (y = 0, facing
// +y; u grows along +x, glTF's v along +z, so the image's up is -z) with a
// one-texel normal map of the given value, scale and, with `mirror_u`, u
// growing along -x instead.
Vec3 mapped_normal(const std::filesystem::path& dir, unsigned char r, unsigned char g,
                   unsigned char b, float scale = 1.0f, bool mirror_u = false) {
  GltfQuad q = gltf_quad();
  if (mirror_u) {
    q.bin.replace(48, 32, floats_bytes({1, 0, 1, 1, 0, 1, 0, 0}));
  }
  write_bytes(dir / "n.png", png_1x1(r, g, b));
  q.doc["images"] = Json::array({{{"uri", "n.png"}}});
  q.doc["textures"] = Json::parse(R"([{"source": 0}])");
  q.doc["materials"][0]["normalTexture"] = {{"index", 0}, {"scale", scale}};
  write_gltf(dir / "n.gltf", q);
  SceneData d = load_scene_data(dir / "n.gltf");
  EXPECT_EQ(d.tangents.size(), d.positions.size());
  for (const SceneData::Tangent& t : d.tangents) {
    expect_near3(t.t, Vec3(mirror_u ? -1.0f : 1.0f, 0, 0), 1e-6f);
    EXPECT_EQ(t.w, mirror_u ? -1.0f : 1.0f);
  }
  Scene scene(std::move(d), std::make_unique<Environment>(Vec3(1.0f)));
  SurfaceHit hit;
  EXPECT_TRUE(scene.intersect(Ray{Vec3(0.3f, 1.0f, 0.6f), Vec3(0, -1, 0)}, &hit));
  expect_near3(hit.ng, Vec3(0, 1, 0), 0.0f);
  return hit.ns;
}

// glTF normalTexture: the texel (2 rgb - 1) in the frame (tangent along +u,
// cross(n, t) w towards the image's up, n), x and y times the scale; the
// tangents are computed from the uvs, so mirrored uvs mirror the frame.
TEST(GltfNormalMaps, TexelBendsTheShadingNormalInTheTangentFrame) {
  TempDir dir("normal_map");
  const float tol = kTexelTolerance;
  // Flat: the normal stays the surface's.
  expect_near3(mapped_normal(dir.path, 128, 128, 255), Vec3(0, 1, 0), tol);
  // A texel that points into the surface is not mirrored out of it: unbent.
  expect_near3(mapped_normal(dir.path, 0, 0, 0), Vec3(0, 1, 0), 0.0f);
  // Red: towards +u (+x here), 30 degrees.
  expect_near3(mapped_normal(dir.path, q8(s30), 128, q8(c30)), Vec3(s30, c30, 0), tol);
  // Green: towards the image's up (-z here).
  expect_near3(mapped_normal(dir.path, 128, q8(s30), q8(c30)), Vec3(0, c30, -s30), tol);
  // Scale 0.5 halves x and y before normalising.
  const Vec3 half = normalize(Vec3(0.5f * s30, c30, 0), Vec3(0));
  expect_near3(mapped_normal(dir.path, q8(s30), 128, q8(c30), 0.5f), half, tol);
  // u growing along -x: red bends towards -x, green still towards the image's up.
  expect_near3(mapped_normal(dir.path, q8(s30), 128, q8(c30), 1.0f, true), Vec3(-s30, c30, 0), tol);
  expect_near3(mapped_normal(dir.path, 128, q8(s30), q8(c30), 1.0f, true), Vec3(0, c30, -s30), tol);
}

// A file's TANGENT (glTF 3.7.2.1) is used instead of the computed tangent:
// the quad given t = +z, w = 1 (so the bitangent cross(n, t) w is +x) bends
// a red texel towards +z and a green one towards +x, where the computed
// frame bends them towards +x and -z.
TEST(GltfNormalMaps, TheFilesTangentsAreUsed) {
  TempDir dir("normal_map_tangent");
  const float tol = kTexelTolerance;
  auto bent = [&](unsigned char r, unsigned char g, unsigned char b) {
    GltfQuad q = gltf_quad();
    add_attribute(&q, "TANGENT", {0, 0, 1, 1});
    add_attribute(&q, "NORMAL", {0, 1, 0});
    write_bytes(dir.path / "n.png", png_1x1(r, g, b));
    q.doc["images"] = Json::array({{{"uri", "n.png"}}});
    q.doc["textures"] = Json::parse(R"([{"source": 0}])");
    q.doc["materials"][0]["normalTexture"] = {{"index", 0}};
    write_gltf(dir.path / "n.gltf", q);
    SceneData d = load_scene_data(dir.path / "n.gltf");
    Scene scene(std::move(d), std::make_unique<Environment>(Vec3(1.0f)));
    SurfaceHit hit;
    EXPECT_TRUE(scene.intersect(Ray{Vec3(0.3f, 1.0f, 0.6f), Vec3(0, -1, 0)}, &hit));
    return hit.ns;
  };
  expect_near3(bent(q8(s30), 128, q8(c30)), Vec3(0, c30, s30), tol);
  expect_near3(bent(128, q8(s30), q8(c30)), Vec3(s30, c30, 0), tol);
}

// Without texture coordinates a normal map has no orientation: it is named
// in a warning and not applied.
TEST(GltfNormalMaps, WithoutTexcoordsTheMapIsWarnedAndIgnored) {
  TempDir dir("normal_map_no_uv");
  GltfQuad q = gltf_quad();
  q.doc["meshes"][0]["primitives"][0]["attributes"].erase("TEXCOORD_0");
  write_bytes(dir.path / "n.png", png_1x1(200, 128, 200));
  q.doc["images"] = Json::array({{{"uri", "n.png"}}});
  q.doc["textures"] = Json::parse(R"([{"source": 0}])");
  q.doc["materials"][0]["name"] = "bumpy";
  q.doc["materials"][0]["normalTexture"] = {{"index", 0}};
  write_gltf(dir.path / "n.gltf", q);
  LogCapture log;
  SceneData d = load_scene_data(dir.path / "n.gltf");
  std::vector<std::string> lines = log.lines();
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("normal maps ignored"), std::string::npos) << lines[0];
  EXPECT_NE(lines[0].find("\"bumpy\""), std::string::npos) << lines[0];
  EXPECT_EQ(d.materials[d.tri_material[0]].normal_tex, -1);
  EXPECT_TRUE(d.tangents.empty());
}

// The quad's material, named `name`, with the material extension `ext_name`
// holding `ext` (none for null), as load_scene_data() reads it.
Material material_with_extension(const std::filesystem::path& dir, const char* name,
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

// KHR_materials_ior as written: IOR 1 (Blender's Principled IOR 1, an
// interface that reflects nothing) is 1, not "unset"; a missing "ior" is the
// extension's default 1.5; a value outside the schema is warned about,
// naming the material, and falls back to 1.5.
TEST(GltfMaterials, IorOneIsReadAsOne) {
  TempDir dir("ior");
  LogCapture log;
  struct Case {
    const char* name;
    Json ext;  // null: no extension
    float ior;
  } cases[] = {{"one", {{"ior", 1.0}}, 1.0f},
               {"water", {{"ior", 1.33}}, 1.33f},
               {"no_key", Json::object(), 1.5f},
               {"none", nullptr, 1.5f},
               {"below", {{"ior", 0.5}}, 1.5f}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    EXPECT_FLOAT_EQ(material_with_extension(dir.path, c.name, "KHR_materials_ior", c.ext).ior,
                    c.ior);
  }
  std::vector<std::string> lines = log.lines();
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("\"below\""), std::string::npos) << lines[0];
  EXPECT_NE(lines[0].find("KHR_materials_ior"), std::string::npos) << lines[0];
}

// KHR_materials_specular's factors as written (what Blender 3.4 exports for
// a Principled BSDF whose Specular is not 0.5: specularColorFactor =
// 0.08 specular / F0(ior)); no extension is factor 1 and white; a value
// outside the schema is warned about, naming the material and the key, and
// the default used; textures are named in a warning (factors only). The
// extension is read, so it is not in the "ignores" warning.
TEST(GltfMaterials, SpecularFactorsAreRead) {
  TempDir dir("specular");
  LogCapture log;
  struct Case {
    const char* name;
    Json ext;  // null: no extension
    float factor;
    Vec3 color;
  } cases[] = {{"blender_specular_0", {{"specularColorFactor", {0.0, 0.0, 0.0}}}, 1.0f, Vec3(0.0f)},
               {"tinted",
                {{"specularFactor", 0.25}, {"specularColorFactor", {2.0, 1.0, 0.5}}},
                0.25f,
                Vec3(2.0f, 1.0f, 0.5f)},
               {"empty", Json::object(), 1.0f, Vec3(1.0f)},
               {"none", nullptr, 1.0f, Vec3(1.0f)},
               {"factor_above", {{"specularFactor", 1.5}}, 1.0f, Vec3(1.0f)},
               {"color_negative", {{"specularColorFactor", {1.0, -1.0, 1.0}}}, 1.0f, Vec3(1.0f)},
               {"textured",
                {{"specularFactor", 0.5}, {"specularTexture", {{"index", 0}}}},
                0.5f,
                Vec3(1.0f)}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Material m = material_with_extension(dir.path, c.name, "KHR_materials_specular", c.ext);
    EXPECT_FLOAT_EQ(m.specular, c.factor);
    expect_near3(m.specular_color, c.color, 0.0f);
  }
  std::vector<std::string> lines = log.lines();
  ASSERT_EQ(lines.size(), 3u);
  EXPECT_NE(lines[0].find("\"factor_above\""), std::string::npos) << lines[0];
  EXPECT_NE(lines[0].find("specularFactor 1.5"), std::string::npos) << lines[0];
  EXPECT_NE(lines[1].find("\"color_negative\""), std::string::npos) << lines[1];
  EXPECT_NE(lines[1].find("specularColorFactor"), std::string::npos) << lines[1];
  EXPECT_NE(lines[2].find("\"textured\""), std::string::npos) << lines[2];
  EXPECT_NE(lines[2].find("specularTexture ignored"), std::string::npos) << lines[2];
  for (const std::string& l : lines)
    EXPECT_EQ(l.find("ignores the glTF extensions"), std::string::npos) << l;
}

TEST(LoadSceneData, EmptyOrCameraOnlyGltfSaysWhy) {
  TempDir dir("empty");
  // What Blender 3.4 exports for an empty scene.
  write_bytes(dir.path / "empty.gltf",
              R"({"asset": {"generator": "Khronos glTF Blender I/O v3.4.50",
    "version": "2.0"}, "scene": 0, "scenes": [{"name": "Scene"}]})");
  write_bytes(dir.path / "camera.gltf", R"({"asset": {"version": "2.0"},
    "scene": 0, "scenes": [{"nodes": [0]}],
    "nodes": [{"camera": 0, "translation": [0, 1, 5]}],
    "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1}}]})");
  for (const char* name : {"empty.gltf", "camera.gltf"}) {
    std::string what = load_error(dir.path / name);
    EXPECT_NE(what.find(name), std::string::npos) << what;
    EXPECT_NE(what.find("has no triangles (0 meshes)"), std::string::npos) << what;
  }
  // Without even a scene: assimp's reason is passed on, never an empty one.
  write_bytes(dir.path / "bare.gltf", R"({"asset": {"version": "2.0"}})");
  std::string what = load_error(dir.path / "bare.gltf");
  EXPECT_NE(what.find("No scene"), std::string::npos) << what;
}

TEST(LoadSceneData, EmissionAboveTheBoundOrInfiniteIsAnErrorNamingTheMaterial) {
  TempDir dir("emission");
  GltfQuad q = gltf_quad();
  q.doc["materials"][0]["name"] = "hot";
  q.doc["materials"][0]["emissiveFactor"] = {1, 1, 1};
  q.doc["materials"][0]["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"] = 1e37;
  write_gltf(dir.path / "hot.gltf", q);
  std::string what = load_error(dir.path / "hot.gltf");
  EXPECT_NE(what.find("\"hot\""), std::string::npos) << what;
  EXPECT_NE(what.find("kMaxRadiance"), std::string::npos) << what;

  q.doc["materials"][0]["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"] = 1e38;
  q.doc["materials"][0]["emissiveFactor"] = {10, 1, 1};  // 1e39 overflows float
  write_gltf(dir.path / "inf.gltf", q);
  what = load_error(dir.path / "inf.gltf");
  EXPECT_NE(what.find("\"hot\""), std::string::npos) << what;
  EXPECT_NE(what.find("non-finite"), std::string::npos) << what;

  // At the bound it loads.
  q.doc["materials"][0]["emissiveFactor"] = {1, 1, 1};
  q.doc["materials"][0]["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"] =
      kMaxRadiance;
  write_gltf(dir.path / "bright.gltf", q);
  SceneData bright = load_scene_data(dir.path / "bright.gltf");
  EXPECT_EQ(bright.materials[bright.tri_material[0]].emission.x, kMaxRadiance);
}

}  // namespace
}  // namespace dofarm::render
