// glTF coverage (docs/renderer.md, "glTF coverage"): textures embedded in a
// .glb or a data: URI, KHR_texture_transform, KHR_lights_punctual in
// Blender's units, the extension warning and refusal, and the load errors of
// empty scenes and out-of-bound emission (materials: test_gltf_materials.cpp).
// The files are written by the tests, except one .glb exported by Blender
// (tests/data/blender/).
#include "tests/render/gltf_fixture.h"
#include "worker/render/camera.h"
#include "worker/render/scene.h"
#include "worker/render/scene_motion.h"

namespace dofarm::render {
namespace {

using namespace gltf_fixture;

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
    EXPECT_EQ(s.materials[s.tri_material[0]].base_color_tex.index, 0);
    expect_same_texture(s.textures[0], t);
    EXPECT_EQ(s.triangle_count(), 2u);
  }
}

// glTF samplers as Blender 3.4 writes them: "Closest" interpolation is
// magFilter NEAREST (9728), "Extend" wraps CLAMP_TO_EDGE (33071), "Mirror"
// MIRRORED_REPEAT (33648). The same image under two samplers is two
// textures; no sampler is bilinear and repeating.
TEST(GltfSamplers, FilterAndWrapAreRead) {
  TempDir dir("samplers");
  write_bytes(dir.path / "tex.png", test_png());
  GltfQuad q = gltf_quad();
  use_base_color_image(&q, {{"uri", "tex.png"}});
  q.doc["samplers"] =
      Json::parse(R"([{"magFilter": 9728, "minFilter": 9984, "wrapS": 33071, "wrapT": 33648}])");
  q.doc["textures"] = Json::parse(R"([{"source": 0, "sampler": 0}, {"source": 0}])");
  q.doc["materials"][0]["emissiveTexture"] = {{"index", 1}};
  q.doc["materials"][0]["emissiveFactor"] = {1.0, 1.0, 1.0};
  write_gltf(dir.path / "samplers.gltf", q);
  SceneData s = load_scene_data(dir.path / "samplers.gltf");
  const Material& m = s.materials[s.tri_material[0]];
  ASSERT_GE(m.base_color_tex.index, 0);
  ASSERT_GE(m.emission_tex.index, 0);
  ASSERT_NE(m.base_color_tex.index, m.emission_tex.index);
  const TextureSampler& a = s.textures[size_t(m.base_color_tex.index)].sampler;
  EXPECT_TRUE(a.nearest);
  EXPECT_EQ(a.wrap_u, TextureWrap::kClamp);
  EXPECT_EQ(a.wrap_v, TextureWrap::kMirror);
  const TextureSampler& b = s.textures[size_t(m.emission_tex.index)].sampler;
  EXPECT_FALSE(b.nearest);
  EXPECT_EQ(b.wrap_u, TextureWrap::kRepeat);
  EXPECT_EQ(b.wrap_v, TextureWrap::kRepeat);
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
  ASSERT_EQ(m.base_color_tex.index, 0);
  const UvTransform& t = m.base_color_tex.uv;
  EXPECT_FALSE(t.is_identity());
  EXPECT_TRUE(m.metal_rough_tex.uv.is_identity());
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
  // This file does not say Blender wrote it (asset.generator): the
  // extension's falloff, not Cycles' (GltfLights.BlenderSpotsAttenuateAsCycles).
  EXPECT_LT(spot.blender_spot_blend, 0.0f);

  const PunctualLight& sun = s.lights[2];
  EXPECT_EQ(sun.type, PunctualLight::Type::kDirectional);
  expect_near3(sun.intensity, Vec3(3.0f), 1e-5f);  // Cycles: strength S gives irradiance S
  // Blender sun rotated 0.5 rad about its x: its -z turns towards -y... in
  // glTF axes, rotation -(pi/2 - 0.5) about x applied to (0, 0, -1).
  const float a = -(float(M_PI) / 2 - 0.5f);
  expect_near3(sun.direction, Vec3(0, std::sin(a), -std::cos(a)), 1e-5f);
}

TEST(GltfLights, AnAnimatedLightMovesWithItsParent) {
  // The light hangs 0.5 below a parent whose static translation (0, 1, 0) is
  // animated: (0, 5, 0) at t = 0, (0, 9, 0) at t = 1. As loaded it is where
  // the static transforms put it; each frame's pose moves it
  // (tests/render/test_scene_motion.cpp has the poses in detail).
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
  {
    LogCapture log;
    SceneData s = load_scene_data(dir.path / "animated.gltf");
    ASSERT_EQ(s.lights.size(), 1u);
    expect_near3(s.lights[0].position, Vec3(0, 0.5f, 0), 1e-5f);
    expect_near3(s.lights[0].intensity, Vec3(1.0f), 1e-6f);  // 683 cd: 1 W/sr
    ASSERT_NE(s.motion, nullptr);
    expect_near3(pose(s, 0.0f).lights[0].position, Vec3(0, 4.5f, 0), 1e-5f);
    expect_near3(pose(s, 0.5f).lights[0].position, Vec3(0, 6.5f, 0), 1e-5f);
    for (const std::string& line : log.lines()) ADD_FAILURE() << "unexpected warning: " << line;
  }
  // The same animation on a parent of the quad (a mesh): the quad moves too,
  // without a warning.
  q.doc["nodes"][1]["children"] = {0, 2};
  q.doc["scenes"][0]["nodes"] = {1};
  write_gltf(dir.path / "moving_mesh.gltf", q);
  LogCapture log;
  SceneData s = load_scene_data(dir.path / "moving_mesh.gltf");
  EXPECT_EQ(s.triangle_count(), 2u);
  ASSERT_NE(s.motion, nullptr);
  EXPECT_EQ(s.motion->parts.size(), 1u);
  expect_near3(s.positions[2], Vec3(1, 1, 1), 1e-6f);
  expect_near3(pose(s, 1.0f).positions[2], Vec3(1, 9, 1), 1e-6f);
  for (const std::string& line : log.lines()) ADD_FAILURE() << "unexpected warning: " << line;
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

// Cycles 3.4's spot (kernel light.h, spot_attenuation), for Blender's spots:
// the cosine to the axis, times a smoothstep over the last (1 - cos theta_s)
// x Blend of the cosine's range. Spot Size 90 degrees, Blend 0.5: at 20
// degrees from the axis (before the blend starts at 31.4) the cosine alone,
// at 35 degrees cos 35 x smoothstep(0.76509) = 0.70478 (computed by hand
// from the definitions), 0 at and beyond 45.
TEST(GltfLights, BlenderSpotsAttenuateAsCycles) {
  const float c45 = std::cos(45.0f * kPi / 180);
  EXPECT_NEAR(cycles_spot_attenuation(1.0f, c45, 0.5f), 1.0f, 1e-6f);
  EXPECT_NEAR(cycles_spot_attenuation(std::cos(20.0f * kPi / 180), c45, 0.5f), 0.939693f, 1e-5f);
  EXPECT_NEAR(cycles_spot_attenuation(std::cos(35.0f * kPi / 180), c45, 0.5f), 0.704783f, 1e-5f);
  EXPECT_EQ(cycles_spot_attenuation(c45, c45, 0.5f), 0.0f);
  EXPECT_EQ(cycles_spot_attenuation(std::cos(50.0f * kPi / 180), c45, 0.5f), 0.0f);
  // Blend 0: a hard edge, the cosine up to it.
  EXPECT_NEAR(cycles_spot_attenuation(std::cos(44.0f * kPi / 180), c45, 0.0f),
              std::cos(44.0f * kPi / 180), 1e-6f);
  // The choice by light: a spot Blender wrote carries its Blend
  // (GltfBlenderExport.*), and only such a spot attenuates as Cycles.
  PunctualLight spot;
  spot.type = PunctualLight::Type::kSpot;
  spot.cos_outer = std::cos(0.5f);
  spot.cos_inner = std::cos(0.3f);
  EXPECT_EQ(spot_attenuation(spot, std::cos(0.4f)),
            spot_falloff(std::cos(0.4f), spot.cos_inner, spot.cos_outer));
  spot.blender_spot_blend = 0.4f;
  EXPECT_EQ(spot_attenuation(spot, std::cos(0.4f)),
            cycles_spot_attenuation(std::cos(0.4f), spot.cos_outer, 0.4f));
}

TEST(GltfBlenderExport, TheJobSizesTheLampsAndNamesWhatBlenderLeftOut) {
  // Blender's exporter drops every lamp's Radius and every Sun's Angle, and
  // the World; the job's [lights] and [environment] give them back, and a
  // Blender file without them is named in one warning that says what
  // renders differently and which keys set it.
  JobSpec spec;
  spec.scene = std::filesystem::path(DOFARM_TEST_DATA) / "blender" / "lamps_and_texture.glb";
  {
    LogCapture log;
    SceneData s = load_job_scene_data(spec);
    ASSERT_EQ(s.lights.size(), 3u);
    EXPECT_NE(s.generator.find("Blender"), std::string::npos) << s.generator;
    for (const PunctualLight& l : s.lights) {
      EXPECT_EQ(l.radius, 0.0f);
      EXPECT_EQ(l.cos_half_angle, 1.0f);
      // The file's Spot: Size 60 degrees, Blend 0.25 (cones 30 and 22.5
      // degrees): its Blend comes back, for Cycles' attenuation.
      if (l.type == PunctualLight::Type::kSpot)
        EXPECT_NEAR(l.blender_spot_blend, 0.25f, 1e-5f);
      else
        EXPECT_LT(l.blender_spot_blend, 0.0f);
    }
    ASSERT_EQ(log.lines().size(), 1u);
    EXPECT_NE(log.lines()[0].find("lamps_and_texture.glb"), std::string::npos) << log.lines()[0];
    EXPECT_NE(log.lines()[0].find("lights.radius"), std::string::npos) << log.lines()[0];
    EXPECT_NE(log.lines()[0].find("lights.sun_angle"), std::string::npos) << log.lines()[0];
    EXPECT_NE(log.lines()[0].find("World"), std::string::npos) << log.lines()[0];
  }
  spec.light_radius = 0.25f;
  spec.sun_angle_deg = 0.526f;
  {
    // The lamps sized, the World still missing: the warning names it alone.
    LogCapture log;
    load_job_scene_data(spec);
    ASSERT_EQ(log.lines().size(), 1u);
    EXPECT_EQ(log.lines()[0].find("lights.radius"), std::string::npos) << log.lines()[0];
    EXPECT_NE(log.lines()[0].find("[environment]"), std::string::npos) << log.lines()[0];
  }
  spec.environment = EnvironmentSpec{};
  spec.environment->color = Vec3(0.0509f);
  LogCapture log;
  SceneData s = load_job_scene_data(spec);
  int suns = 0, lamps = 0;
  for (const PunctualLight& l : s.lights) {
    if (l.type == PunctualLight::Type::kDirectional) {
      ++suns;
      EXPECT_EQ(l.radius, 0.0f);
      EXPECT_NEAR(l.cos_half_angle, std::cos(0.263 * M_PI / 180), 1e-7);
    } else {
      ++lamps;
      EXPECT_EQ(l.radius, 0.25f);
      EXPECT_EQ(l.cos_half_angle, 1.0f);
    }
  }
  EXPECT_EQ(suns, 1);
  EXPECT_EQ(lamps, 2);
  for (const std::string& line : log.lines()) ADD_FAILURE() << "unexpected warning: " << line;
}

TEST(GltfBlenderExport, OneLampIsSizedByItsName) {
  // lamps_and_texture.glb's lamps are the nodes "Point", "Spot" and "Sun".
  JobSpec spec;
  spec.scene = std::filesystem::path(DOFARM_TEST_DATA) / "blender" / "lamps_and_texture.glb";
  spec.light_radius = 0.25f;
  spec.environment = EnvironmentSpec{};
  spec.environment->color = Vec3(0.0509f);
  spec.lamp_sizes.push_back({"Spot", 0.05f, -1.0f, 0});
  spec.lamp_sizes.push_back({"Sun", -1.0f, 2.0f, 1});
  {
    LogCapture log;
    SceneData s = load_job_scene_data(spec);
    for (const PunctualLight& l : s.lights) {
      if (l.name == "Point") {
        EXPECT_EQ(l.radius, 0.25f);  // the table's own
      }
      if (l.name == "Spot") {
        EXPECT_EQ(l.radius, 0.05f);
      }
      if (l.name == "Sun") {
        EXPECT_NEAR(l.cos_half_angle, std::cos(1.0 * M_PI / 180), 1e-7);
      }
    }
    for (const std::string& line : log.lines()) ADD_FAILURE() << "unexpected warning: " << line;
  }
  // A name the scene does not have: an error at the entry's name, listing
  // the lamps there are.
  spec.lamp_sizes.push_back({"Key", 0.1f, -1.0f, 2});
  try {
    load_job_scene_data(spec);
    FAIL() << "sized a lamp the scene does not have";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "lights.lamp.2.name");
    EXPECT_NE(std::string(e.what()).find("\"Point\", \"Spot\", \"Sun\""), std::string::npos)
        << e.what();
  }
  // A size of the other kind: a radius for the Sun.
  spec.lamp_sizes = {{"Sun", 0.1f, -1.0f, 0}};
  try {
    load_job_scene_data(spec);
    FAIL() << "gave a sun a radius";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "lights.lamp.0.radius");
    EXPECT_NE(std::string(e.what()).find("sun_angle"), std::string::npos) << e.what();
  }
}

TEST(GltfLights, AFileNotFromBlenderKeepsPointLampsWithoutAWord) {
  TempDir dir("lights_other_generator");
  GltfQuad q = gltf_quad();
  q.doc["asset"]["generator"] = "some other exporter";
  q.doc["nodes"].push_back(Json::parse(
      R"({"name": "lamp", "translation": [0, 1, 0],
          "extensions": {"KHR_lights_punctual": {"light": 0}}})"));
  q.doc["scenes"][0]["nodes"].push_back(1);
  q.doc["extensions"]["KHR_lights_punctual"]["lights"] =
      Json::parse(R"([{"type": "point", "intensity": 683}])");
  q.doc["extensionsUsed"] = {"KHR_lights_punctual"};
  write_gltf(dir.path / "other.gltf", q);
  JobSpec spec;
  spec.scene = dir.path / "other.gltf";
  LogCapture log;
  SceneData s = load_job_scene_data(spec);
  EXPECT_EQ(s.generator, "some other exporter");
  ASSERT_EQ(s.lights.size(), 1u);
  EXPECT_EQ(s.lights[0].radius, 0.0f);
  for (const std::string& line : log.lines()) ADD_FAILURE() << "unexpected warning: " << line;
}

TEST(GltfBlenderExport, LampsEmbeddedTextureAndMappingAsBlenderMeantThem) {
  // A .glb from Blender 3.4 (tests/data/blender/make_lamps_and_texture.py).
  const auto dir = std::filesystem::path(DOFARM_TEST_DATA) / "blender";
  SceneData s = load_scene_data(dir / "lamps_and_texture.glb");
  ASSERT_EQ(s.triangle_count(), 2u);
  const Material& m = s.materials[s.tri_material[0]];
  ASSERT_EQ(m.base_color_tex.index, 0);
  // The PNG inside the .glb decodes exactly like the file it was made from.
  RgbImage beside = load_rgb_image(dir / "tex.png", /*srgb=*/true);
  EXPECT_EQ(s.textures[0].width, beside.width);
  EXPECT_EQ(s.textures[0].height, beside.height);
  EXPECT_EQ(s.textures[0].rgb, beside.rgb);
  for (Vec2 uv : {Vec2(0, 0), Vec2(1, 1), Vec2(0.2f, 0.9f)}) {
    Vec2 want = blender_mapping(uv, Vec2(0.25f, 0.5f), 0.3f, Vec2(2, 3));
    EXPECT_NEAR(m.base_color_tex.uv.apply(uv).x, want.x, 1e-5f);
    EXPECT_NEAR(m.base_color_tex.uv.apply(uv).y, want.y, 1e-5f);
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
  q.doc["extensionsUsed"] = {"KHR_materials_anisotropy", "KHR_texture_transform"};
  q.doc["extensionsRequired"] = {"KHR_materials_anisotropy"};
  write_gltf(dir.path / "required.gltf", q);
  std::string what = load_error(dir.path / "required.gltf");
  EXPECT_NE(what.find("KHR_materials_anisotropy"), std::string::npos) << what;
  EXPECT_NE(what.find("extensionsRequired"), std::string::npos) << what;
  EXPECT_EQ(what.find("KHR_texture_transform,"), std::string::npos) << what;
}

TEST(GltfExtensions, UsedButUnimplementedAreNamedInOneWarning) {
  TempDir dir("used");
  GltfQuad q = gltf_quad();
  q.doc["extensionsUsed"] = {"KHR_materials_anisotropy", "KHR_lights_punctual",
                             "KHR_materials_iridescence"};
  write_gltf(dir.path / "used.gltf", q);
  LogCapture log;
  SceneData s = load_scene_data(dir.path / "used.gltf");
  std::vector<std::string> lines = log.lines();
  EXPECT_EQ(s.triangle_count(), 2u);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("used.gltf"), std::string::npos) << lines[0];
  EXPECT_NE(lines[0].find("KHR_materials_anisotropy, KHR_materials_iridescence"), std::string::npos)
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

// A primitive without a material gets glTF's default material (white
// metal, roughness 1), as the specification says, and a warning names its
// mesh: Blender shows an object without a material in a grey diffuse
// surface, and its exporter writes it without one.
TEST(GltfMaterials, AMeshWithoutAMaterialIsNamedAndGetsGltfsDefault) {
  TempDir dir("unmaterialled");
  GltfQuad q = gltf_quad();
  q.doc["meshes"][0]["name"] = "Floor";
  q.doc["meshes"][0]["primitives"][0].erase("material");
  write_gltf(dir.path / "bare.gltf", q);
  LogCapture log;
  SceneData s = load_scene_data(dir.path / "bare.gltf");
  const std::vector<std::string> lines = log.lines();
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("\"Floor\" without a material"), std::string::npos) << lines[0];
  const Material& m = s.materials[s.tri_material[0]];
  expect_near3(m.base_color, Vec3(1.0f), 0.0f);
  EXPECT_EQ(m.metallic, 1.0f);
  EXPECT_EQ(m.roughness, 1.0f);
  // With its material, no warning.
  write_gltf(dir.path / "with.gltf", gltf_quad());
  LogCapture none;
  load_scene_data(dir.path / "with.gltf");
  EXPECT_TRUE(none.lines().empty()) << none.lines().front();
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

// An orthographic camera (Blender's Orthographic type) is read with its
// film (xmag, ymag) and clipping planes, and a frame through it is
// orthographic; one whose ymag glTF forbids (0) is refused where a job
// takes it, naming the camera and why; a job with its own poses still
// loads the scene.
TEST(LoadSceneData, AnOrthographicCameraIsReadFromItsXmagAndYmag) {
  TempDir dir("ortho");
  GltfQuad q = gltf_quad();
  q.doc["nodes"].push_back(Json::parse(R"({"name": "Plan", "camera": 0,
      "translation": [0, 5, 0], "rotation": [-0.7071068, 0, 0, 0.7071068]})"));
  q.doc["scenes"][0]["nodes"].push_back(q.doc["nodes"].size() - 1);
  q.doc["cameras"] = Json::parse(R"([{"name": "Plan", "type": "orthographic",
      "orthographic": {"xmag": 2.0, "ymag": 1.0, "znear": 0.1, "zfar": 100}}])");
  write_gltf(dir.path / "ortho.gltf", q);
  const SceneData o = load_scene_data(dir.path / "ortho.gltf");
  EXPECT_TRUE(o.camera_refused.empty()) << o.camera_refused;
  ASSERT_TRUE(o.scene_camera);
  EXPECT_EQ(o.scene_camera->ymag, 1.0f);
  EXPECT_EQ(o.scene_camera->aspect, 2.0f);
  EXPECT_EQ(o.scene_camera->znear, 0.1f);
  EXPECT_EQ(o.scene_camera->zfar, 100.0f);
  JobSpec ortho_spec;
  ortho_spec.width = 64;
  ortho_spec.height = 32;
  ortho_spec.camera_from_scene = true;
  const CameraState oc = camera_for_frame(ortho_spec, o, 0);
  EXPECT_EQ(oc.ortho_height, 2.0f);
  EXPECT_EQ(oc.fov_deg, 0.0f);
  EXPECT_NEAR(oc.position[1], 5.0f, 1e-6f);

  q.doc["cameras"] = Json::parse(R"([{"name": "Plan", "type": "orthographic",
      "orthographic": {"xmag": 2.0, "ymag": 0.0, "znear": 0.1, "zfar": 100}}])");
  write_gltf(dir.path / "flat.gltf", q);
  SceneData s = load_scene_data(dir.path / "flat.gltf");
  EXPECT_TRUE(s.camera_track.empty());
  EXPECT_NE(s.camera_refused.find("orthographic with xmag 2 and ymag 0"), std::string::npos)
      << s.camera_refused;
  EXPECT_NE(s.camera_refused.find("\"Plan\""), std::string::npos) << s.camera_refused;
  JobSpec spec;
  spec.width = spec.height = 8;
  spec.camera_from_scene = true;
  spec.key_locations["camera.from_scene"] = FileLoc{"job.toml", 3, 1};
  try {
    camera_for_frame(spec, s, 0);
    FAIL() << "rendered an orthographic camera of height 0";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "camera.from_scene");
    EXPECT_NE(std::string(e.what()).find("orthographic"), std::string::npos) << e.what();
  }
  // The same node with a perspective camera is the scene's camera.
  q.doc["cameras"] = Json::parse(R"([{"name": "Plan", "type": "perspective",
      "perspective": {"yfov": 0.7, "znear": 0.1}}])");
  write_gltf(dir.path / "persp.gltf", q);
  SceneData p = load_scene_data(dir.path / "persp.gltf");
  EXPECT_EQ(p.camera_track.size(), 1u);
  EXPECT_TRUE(p.camera_refused.empty());
}

// A file with several cameras (a Blender scene exports all of them, the
// active one not marked): the first is the scene camera unless the job
// names another; a name the file lacks leaves no camera, and says why.
TEST(LoadSceneData, TheSceneCameraIsTheFirstOrTheOneNamed) {
  TempDir dir("two_cameras");
  GltfQuad q = gltf_quad();
  q.doc["nodes"].push_back(Json::parse(R"({"name": "Plan", "camera": 0,
      "translation": [0, 5, 0], "rotation": [-0.7071068, 0, 0, 0.7071068]})"));
  q.doc["nodes"].push_back(Json::parse(R"({"name": "Front", "camera": 1,
      "translation": [0, 0, 4]})"));
  q.doc["scenes"][0]["nodes"].push_back(q.doc["nodes"].size() - 2);
  q.doc["scenes"][0]["nodes"].push_back(q.doc["nodes"].size() - 1);
  q.doc["cameras"] = Json::parse(R"([
      {"type": "orthographic", "orthographic": {"xmag": 2.0, "ymag": 1.0, "znear": 0.1, "zfar": 100}},
      {"type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}}])");
  write_gltf(dir.path / "two.gltf", q);

  const SceneData first = load_scene_data(dir.path / "two.gltf");
  ASSERT_EQ(first.camera_names.size(), 2u);
  ASSERT_TRUE(first.scene_camera);
  EXPECT_EQ(first.scene_camera->name, first.camera_names[0]);
  const std::string other = first.camera_names[1];
  EXPECT_TRUE((first.camera_names[0] == "Plan" && other == "Front") ||
              (first.camera_names[0] == "Front" && other == "Plan"))
      << first.camera_names[0] << ", " << other;

  const SceneData named = load_scene_data(dir.path / "two.gltf", other);
  ASSERT_TRUE(named.scene_camera);
  EXPECT_EQ(named.scene_camera->name, other);
  EXPECT_EQ(named.camera_names, first.camera_names);
  JobSpec spec;
  spec.width = 64;
  spec.height = 32;
  spec.camera_from_scene = true;
  const CameraState plan =
      camera_for_frame(spec, load_scene_data(dir.path / "two.gltf", "Plan"), 0);
  EXPECT_EQ(plan.ortho_height, 2.0f);
  EXPECT_NEAR(plan.position[1], 5.0f, 1e-6f);
  const CameraState front =
      camera_for_frame(spec, load_scene_data(dir.path / "two.gltf", "Front"), 0);
  EXPECT_EQ(front.ortho_height, 0.0f);
  EXPECT_NEAR(front.fov_deg, 0.5f * 180.0f / float(M_PI), 1e-4f);
  EXPECT_NEAR(front.position[2], 4.0f, 1e-6f);

  const SceneData missing = load_scene_data(dir.path / "two.gltf", "Side");
  EXPECT_FALSE(missing.scene_camera);
  EXPECT_TRUE(missing.camera_track.empty());
  EXPECT_NE(missing.camera_refused.find("no camera named \"Side\""), std::string::npos)
      << missing.camera_refused;
  EXPECT_NE(missing.camera_refused.find("\"Front\""), std::string::npos) << missing.camera_refused;
}

// A Blender file without a camera (Blender 3.4 exports cameras only with
// Include > Cameras ticked): the refusal says where the checkbox is; a
// file from elsewhere gets the plain message.
TEST(LoadSceneData, ABlenderFileWithoutACameraNamesTheExportersCheckbox) {
  const auto path = std::filesystem::path(DOFARM_TEST_DATA) / "blender" / "lamps_and_texture.glb";
  SceneData s = load_scene_data(path);
  ASSERT_FALSE(s.scene_camera);
  const std::string blender = no_scene_camera_message(s, path.string());
  EXPECT_NE(blender.find("has no camera (Blender writes its cameras into glTF only with "
                         "Include > Cameras ticked)"),
            std::string::npos)
      << blender;
  s.generator = "another exporter";
  const std::string other = no_scene_camera_message(s, path.string());
  EXPECT_EQ(other.find("Blender"), std::string::npos) << other;
  EXPECT_NE(other.find("has no camera; add one"), std::string::npos) << other;
}

// The scene camera's clipping planes come from the file's JSON: znear and
// zfar as given, no zfar = none (assimp alone would say 100), and planes
// glTF does not allow (zfar not beyond znear) named in a warning and left
// out.
TEST(LoadSceneData, TheCamerasClippingPlanesAreTheFiles) {
  TempDir dir("camera_clip_planes");
  GltfQuad q = gltf_quad();
  q.doc["nodes"].push_back(
      Json::parse(R"({"name": "Cam", "camera": 0, "translation": [0, 5, 0]})"));
  q.doc["scenes"][0]["nodes"].push_back(q.doc["nodes"].size() - 1);
  auto planes = [&](const char* perspective, std::vector<std::string>* warnings) {
    q.doc["cameras"] =
        Json::array({{{"type", "perspective"}, {"perspective", Json::parse(perspective)}}});
    write_gltf(dir.path / "cam.gltf", q);
    LogCapture log;
    SceneData s = load_scene_data(dir.path / "cam.gltf");
    *warnings = log.lines();
    return std::pair{s.scene_camera->znear, s.scene_camera->zfar};
  };
  std::vector<std::string> warnings;
  EXPECT_EQ(planes(R"({"yfov": 0.7, "znear": 0.25, "zfar": 40})", &warnings),
            std::pair(0.25f, 40.0f));
  EXPECT_TRUE(warnings.empty());
  const auto open = planes(R"({"yfov": 0.7, "znear": 0.25})", &warnings);
  EXPECT_EQ(open.first, 0.25f);
  EXPECT_TRUE(std::isinf(open.second));
  EXPECT_TRUE(warnings.empty());
  const auto bad = planes(R"({"yfov": 0.7, "znear": 0.25, "zfar": 0.1})", &warnings);
  EXPECT_EQ(bad.first, 0.25f);
  EXPECT_TRUE(std::isinf(bad.second));
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("\"Cam\" has zfar 0.1"), std::string::npos) << warnings[0];
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
