// Meshes and lights moved by the scene file's node animation
// (worker/render/scene_motion.h): the transforms against hand-computed
// values, glTF samplers (LINEAR, STEP, CUBICSPLINE) of transforms and
// morph weights through the loader, the file's tangents, and frames
// rendered where the moving quad is at each frame's time.
#include <gtest/gtest.h>

#include <cmath>
#include <tuple>

#include "tests/render/gltf_fixture.h"
#include "tests/render/render_fixtures.h"
#include "worker/render/render_job.h"
#include "worker/render/scene_motion.h"

namespace dofarm::render {
namespace {

using gltf_fixture::expect_near3;
using gltf_fixture::floats_bytes;
using gltf_fixture::GltfQuad;
using gltf_fixture::Json;
using gltf_fixture::LogCapture;
using gltf_fixture::TempDir;

Quat about_axis(Vec3 axis, float radians) {
  const Vec3 a = normalize(axis) * std::sin(0.5f * radians);
  return Quat{std::cos(0.5f * radians), a.x, a.y, a.z};
}

TEST(Affine, TrsIsTranslationAfterRotationAfterScale) {
  const Quat r = about_axis(Vec3(0, 0, 1), 0.5f * kPi);  // x -> y
  const Affine a = Affine::trs(Vec3(1, 2, 3), r, Vec3(2, 3, 4));
  // (1, 1, 1) scaled (2, 3, 4), turned a quarter about z (-3, 2, 4), moved.
  expect_near3(a.point(Vec3(1, 1, 1)), Vec3(-2, 4, 7), 1e-5f);
  EXPECT_NEAR(a.determinant(), 24.0f, 1e-4f);
  // Composition: b after a.
  const Affine b = Affine::trs(Vec3(0, 0, -1), Quat{}, Vec3(1, 1, 2));
  expect_near3((b * a).point(Vec3(1, 1, 1)), Vec3(-2, 4, 13), 1e-5f);
}

TEST(Affine, NormalsStayPerpendicularAndSurviveSingularScale) {
  const Affine a = Affine::trs(Vec3(0.0f), about_axis(Vec3(1, 2, 3), 0.7f), Vec3(3, 0.5f, 1));
  // Two directions in a surface, and its normal.
  const Vec3 u = normalize(Vec3(1, -1, 0)), v = normalize(Vec3(0, 1, -2));
  const Vec3 n = normalize(cross(u, v));
  const Vec3 n2 = normalize(a.normal(n));
  EXPECT_NEAR(dot(n2, a.linear(u)), 0.0f, 1e-5f);
  EXPECT_NEAR(dot(n2, a.linear(v)), 0.0f, 1e-5f);
  EXPECT_GT(dot(n2, cross(a.linear(u), a.linear(v))), 0.0f);  // the same side
  // A mirror keeps the normal on the side the inverse transpose gives.
  const Affine m = Affine::trs(Vec3(0.0f), Quat{}, Vec3(-1, 1, 1));
  expect_near3(normalize(m.normal(Vec3(1, 0, 0))), Vec3(-1, 0, 0), 1e-6f);
  expect_near3(normalize(m.normal(Vec3(0, 1, 0))), Vec3(0, 1, 0), 1e-6f);
  // Scaled to nothing (an object hidden by scale 0): no NaN, a zero normal.
  const Affine z = Affine::trs(Vec3(0.0f), Quat{}, Vec3(0.0f));
  const Vec3 nz = z.normal(Vec3(0, 0, 1));
  EXPECT_TRUE(is_finite(nz));
  EXPECT_EQ(length(nz), 0.0f);
}

TEST(MotionNode, TracksInterpolateClampAndStep) {
  MotionNode n;
  n.translation = Vec3(7, 7, 7);  // stands in for a property without keys
  n.scale = Vec3(1.0f);
  n.translation_keys.times = {1.0f, 3.0f};
  n.translation_keys.values = {Vec3(0, 0, 0), Vec3(4, 0, 0)};
  n.rotation_keys.times = {0.0f, 2.0f};
  n.rotation_keys.values = {Quat{}, about_axis(Vec3(0, 1, 0), kPi * 0.5f)};
  expect_near3(n.local(0.0f).point(Vec3(0.0f)), Vec3(0, 0, 0), 1e-6f);  // clamped before
  expect_near3(n.local(2.0f).point(Vec3(0.0f)), Vec3(2, 0, 0), 1e-6f);
  expect_near3(n.local(9.0f).point(Vec3(0.0f)), Vec3(4, 0, 0), 1e-6f);  // clamped after
  // Spherical: halfway through a quarter turn about y is 45 degrees.
  expect_near3(n.local(1.0f).linear(Vec3(1, 0, 0)), Vec3(std::cos(kPi / 4), 0, -std::sin(kPi / 4)),
               1e-5f);
  expect_near3(n.local(2.0f).linear(Vec3(1, 0, 0)), Vec3(0, 0, -1), 1e-5f);
  n.translation_keys.step = true;
  expect_near3(n.local(2.9f).point(Vec3(0.0f)), Vec3(0, 0, 0), 1e-6f);
  expect_near3(n.local(3.0f).point(Vec3(0.0f)), Vec3(4, 0, 0), 1e-6f);
  // Without keys: the node's fixed transform.
  MotionNode still;
  still.fixed = Affine::trs(Vec3(1, 2, 3), Quat{}, Vec3(1.0f));
  expect_near3(still.local(5.0f).point(Vec3(0.0f)), Vec3(1, 2, 3), 1e-6f);
}

// Appends an animation sampler of `values` (VEC3 or VEC4 per key) at `times`
// targeting node `node`'s `path`, as its own animation.
void add_channel(GltfQuad* q, int node, const char* path, const std::vector<float>& times,
                 const std::vector<float>& values, const char* interpolation = "LINEAR") {
  // CUBICSPLINE: in-tangent, value, out-tangent per key (glTF Appendix C).
  const size_t per_key = std::string(interpolation) == "CUBICSPLINE" ? 3 : 1;
  const int width = int(values.size() / (per_key * times.size()));
  auto view = [&](const std::vector<float>& v) {
    while (q->bin.size() % 4) q->bin += '\0';
    const size_t at = q->bin.size();
    q->bin.append(reinterpret_cast<const char*>(v.data()), v.size() * 4);
    q->doc["bufferViews"].push_back(
        {{"buffer", 0}, {"byteOffset", at}, {"byteLength", 4 * v.size()}});
    return q->doc["bufferViews"].size() - 1;
  };
  const size_t in_view = view(times), out_view = view(values);
  const float lo = *std::min_element(times.begin(), times.end());
  const float hi = *std::max_element(times.begin(), times.end());
  q->doc["accessors"].push_back({{"bufferView", in_view},
                                 {"componentType", 5126},
                                 {"count", times.size()},
                                 {"type", "SCALAR"},
                                 {"min", {lo}},
                                 {"max", {hi}}});
  q->doc["accessors"].push_back({{"bufferView", out_view},
                                 {"componentType", 5126},
                                 {"count", per_key * times.size()},
                                 {"type", width == 4   ? "VEC4"
                                          : width == 3 ? "VEC3"
                                                       : "SCALAR"}});
  const size_t acc = q->doc["accessors"].size();
  Json anim;
  anim["channels"] = {{{"sampler", 0}, {"target", {{"node", node}, {"path", path}}}}};
  anim["samplers"] = {{{"input", acc - 2}, {"output", acc - 1}, {"interpolation", interpolation}}};
  q->doc["animations"].push_back(anim);
}

// The quad (node 0, static scale 2 in x) under node 1 "rig" at (0, 1, 0).
GltfQuad quad_on_rig() {
  GltfQuad q = gltf_fixture::gltf_quad();
  q.doc["nodes"][0]["scale"] = {2, 1, 1};
  q.doc["nodes"].push_back(Json::parse(R"({"name": "rig", "translation": [0, 1, 0],
                                           "children": [0]})"));
  q.doc["scenes"][0]["nodes"] = {1};
  return q;
}

SceneData load(const TempDir& dir, const char* name, const GltfQuad& q) {
  gltf_fixture::write_gltf(dir.path / name, q);
  return load_scene_data(dir.path / name);
}

// load(), and a failure for every warning the loader logs.
SceneData load_without_warnings(const TempDir& dir, const char* name, const GltfQuad& q) {
  LogCapture log;
  SceneData s = load(dir, name, q);
  for (const std::string& line : log.lines()) ADD_FAILURE() << "unexpected warning: " << line;
  return s;
}

TEST(SceneMotion, AMeshFollowsItsAnimatedParent) {
  TempDir dir("motion_parent");
  GltfQuad q = quad_on_rig();
  add_channel(&q, 1, "translation", {0, 1}, {0, 5, 0, 0, 9, 0});
  add_channel(&q, 1, "rotation", {0, 2}, {0, 0, 0, 1, 0, std::sqrt(0.5f), 0, std::sqrt(0.5f)});
  SceneData s = load_without_warnings(dir, "parent.gltf", q);
  ASSERT_NE(s.motion, nullptr);
  ASSERT_EQ(s.motion->parts.size(), 1u);
  // As loaded: the nodes' own transforms; vertex 2 = (1, 0, 1) -> (2, 1, 1).
  expect_near3(s.positions[2], Vec3(2, 1, 1), 1e-6f);
  // t = 0.5: the rig at (0, 7, 0), turned an eighth about y (half of the
  // quarter turn that takes 2 s): (2, 0, 1) turned, then moved.
  const float a = kPi / 8;
  const Vec3 turned(2 * std::cos(a) + std::sin(a), 0, -2 * std::sin(a) + std::cos(a));
  SceneData p = pose(s, 0.5f);
  expect_near3(p.positions[2], turned + Vec3(0, 7, 0), 1e-5f);
  expect_near3(p.positions[0], Vec3(0, 7, 0), 1e-5f);
  // The normal turns with the quad and stays +y; nothing else changes.
  expect_near3(p.normals[2], Vec3(0, 1, 0), 1e-5f);
  EXPECT_EQ(p.indices, s.indices);
  ASSERT_EQ(p.uvs.size(), s.uvs.size());
  for (size_t v = 0; v < p.uvs.size(); ++v) EXPECT_EQ(p.uvs[v].x, s.uvs[v].x);
  EXPECT_TRUE(p.textures.empty());
  // Clamped after the last key: t = 5 is t = 1 for the translation, t = 2
  // for the rotation: (2, 0, 1) a quarter turn about y is (1, 0, -2).
  expect_near3(pose(s, 5.0f).positions[2], Vec3(1, 9, -2), 1e-5f);
}

TEST(SceneMotion, StepSamplersHoldTheirKey) {
  TempDir dir("motion_step");
  GltfQuad q = quad_on_rig();
  add_channel(&q, 1, "translation", {0, 1}, {0, 0, 0, 0, 4, 0}, "STEP");
  SceneData s = load(dir, "step.gltf", q);
  ASSERT_NE(s.motion, nullptr);
  expect_near3(pose(s, 0.99f).positions[0], Vec3(0, 0, 0), 1e-6f);
  expect_near3(pose(s, 1.0f).positions[0], Vec3(0, 4, 0), 1e-6f);
  // The same sampler as LINEAR moves it smoothly.
  GltfQuad linear = quad_on_rig();
  add_channel(&linear, 1, "translation", {0, 1}, {0, 0, 0, 0, 4, 0});
  expect_near3(pose(load(dir, "linear.gltf", linear), 0.5f).positions[0], Vec3(0, 2, 0), 1e-6f);
}

TEST(SceneMotion, AMirroringScaleKeepsTheFrontFace) {
  // Scale x from 1 to -1: past 0 the transform mirrors, and the winding
  // must turn with it so that the triangles' front still faces the normals.
  TempDir dir("motion_mirror");
  GltfQuad q = quad_on_rig();
  add_channel(&q, 1, "scale", {0, 1}, {1, 1, 1, -1, 1, 1});
  SceneData s = load(dir, "mirror.gltf", q);
  ASSERT_NE(s.motion, nullptr);
  for (float t : {0.0f, 0.25f, 1.0f}) {
    SceneData p = pose(s, t);
    for (size_t k = 0; k + 2 < p.indices.size(); k += 3) {
      const Vec3 p0 = p.positions[p.indices[k]], p1 = p.positions[p.indices[k + 1]],
                 p2 = p.positions[p.indices[k + 2]];
      const Vec3 ng = cross(p1 - p0, p2 - p0);
      EXPECT_GT(dot(ng, p.normals[p.indices[k]]), 0.0f) << "t = " << t << ", triangle " << k / 3;
    }
  }
  // Scaled to 0 at t = 0.5: every vertex collapses onto the plane x = 0,
  // finite, with zero normals (the geometric normal stands in).
  SceneData flat = pose(s, 0.5f);
  for (size_t v = 0; v < flat.positions.size(); ++v) {
    EXPECT_NEAR(flat.positions[v].x, 0.0f, 1e-6f);
    EXPECT_TRUE(is_finite(flat.normals[v]));
  }
}

TEST(SceneMotion, ALightFollowsItsNode) {
  // The lamp hangs 0.5 below the rig, which moves (0, 5, 0) -> (0, 9, 0)
  // over the first second; the quad stays.
  TempDir dir("motion_light");
  GltfQuad q = gltf_fixture::gltf_quad();
  q.doc["nodes"].push_back(
      Json::parse(R"({"name": "rig", "translation": [0, 1, 0], "children": [2]})"));
  q.doc["nodes"].push_back(Json::parse(R"({"name": "lamp", "translation": [0, -0.5, 0],
      "extensions": {"KHR_lights_punctual": {"light": 0}}})"));
  q.doc["scenes"][0]["nodes"] = {0, 1};
  q.doc["extensions"]["KHR_lights_punctual"]["lights"] =
      Json::parse(R"([{"type": "point", "intensity": 683}])");
  q.doc["extensionsUsed"] = {"KHR_lights_punctual"};
  add_channel(&q, 1, "translation", {0, 1}, {0, 5, 0, 0, 9, 0});
  SceneData s = load(dir, "light.gltf", q);
  ASSERT_EQ(s.lights.size(), 1u);
  ASSERT_NE(s.motion, nullptr);
  EXPECT_TRUE(s.motion->parts.empty());                         // the quad does not move
  expect_near3(s.lights[0].position, Vec3(0, 0.5f, 0), 1e-6f);  // the nodes' own transforms
  expect_near3(pose(s, 0.0f).lights[0].position, Vec3(0, 4.5f, 0), 1e-6f);
  expect_near3(pose(s, 0.25f).lights[0].position, Vec3(0, 5.5f, 0), 1e-6f);
  expect_near3(pose(s, 1.0f).lights[0].position, Vec3(0, 8.5f, 0), 1e-6f);
  expect_near3(pose(s, 1.0f).lights[0].intensity, Vec3(1.0f), 1e-6f);
  // The light's irradiance on the quad below it falls as it rises: 1 / d^2.
  auto lit = [&](float t) {
    auto scene = std::make_shared<Scene>(pose(s, t), nullptr);
    LightSample ls;
    EXPECT_TRUE(scene->sample_light(Vec3(0.5f, 0, 0.5f), 0.5f, Vec2(0.5f, 0.5f), &ls));
    return ls.radiance.x;
  };
  const auto d2 = [](float y) { return 0.25f + y * y + 0.25f; };
  EXPECT_NEAR(lit(0.0f) / lit(1.0f), d2(8.5f) / d2(4.5f), 1e-4f);
}

TEST(SceneMotion, APoseThatMovesOnlyLampsTracesThroughTheLoadedBvh) {
  // ALightFollowsItsNode's rig: the lamp moves, the quad (y = 0, x and z
  // in [0, 1]) stays. A pose shares the loaded scene's BVH instead of
  // building its own, and keeps it when the loaded scene is gone.
  TempDir dir("motion_lamp_only");
  auto rig = [](GltfQuad* q) {
    q->doc["nodes"].push_back(
        Json::parse(R"({"name": "rig", "translation": [0, 1, 0], "children": [2]})"));
    q->doc["nodes"].push_back(Json::parse(R"({"name": "lamp", "translation": [0, -0.5, 0],
        "extensions": {"KHR_lights_punctual": {"light": 0}}})"));
    q->doc["scenes"][0]["nodes"] = {0, 1};
    q->doc["extensions"]["KHR_lights_punctual"]["lights"] =
        Json::parse(R"([{"type": "point", "intensity": 683}])");
    q->doc["extensionsUsed"] = {"KHR_lights_punctual"};
    add_channel(q, 1, "translation", {0, 1}, {0, 5, 0, 0, 9, 0});
  };
  const Ray down{Vec3(0.25f, 3, 0.5f), Vec3(0, -1, 0)};
  const Ray beside{Vec3(1.5f, 3, 0.5f), Vec3(0, -1, 0)};
  {
    GltfQuad q = gltf_fixture::gltf_quad();
    rig(&q);
    auto loaded = std::make_shared<Scene>(load(dir, "lamp.gltf", q), nullptr);
    const std::shared_ptr<const Scene> posed = loaded->at_time(0.5f);
    ASSERT_NE(posed.get(), loaded.get());
    EXPECT_TRUE(posed->shares_bvh_with(*loaded));
    EXPECT_TRUE(loaded->at_time(1.0f)->shares_bvh_with(*posed));
    expect_near3(posed->data().lights[0].position, Vec3(0, 6.5f, 0), 1e-5f);
    loaded.reset();
    SurfaceHit hit;
    ASSERT_TRUE(posed->intersect(down, &hit));
    EXPECT_NEAR(hit.t, 3.0f, 1e-5f);
    expect_near3(hit.p, Vec3(0.25f, 0, 0.5f), 1e-6f);
    EXPECT_FALSE(posed->intersect(beside, &hit));
    EXPECT_TRUE(posed->occluded(down.o, down.d, 4.0f));
    EXPECT_FALSE(posed->occluded(down.o, down.d, 2.9f));
  }
  {  // The quad moves too (0 -> 2 in y over the first second): each pose
     // builds its BVH where the quad is then.
    GltfQuad q = gltf_fixture::gltf_quad();
    rig(&q);
    add_channel(&q, 0, "translation", {0, 1}, {0, 0, 0, 0, 2, 0});
    auto loaded = std::make_shared<Scene>(load(dir, "both.gltf", q), nullptr);
    const std::shared_ptr<const Scene> posed = loaded->at_time(0.5f);
    EXPECT_FALSE(posed->shares_bvh_with(*loaded));
    SurfaceHit hit;
    ASSERT_TRUE(posed->intersect(down, &hit));
    EXPECT_NEAR(hit.t, 2.0f, 1e-5f);
  }
  {  // Alpha masks: the quad is cut out where x < 0.5 (u = x; a 2 x 1 RGBA
     // texture, alpha 0 then 1). The pose shares the BVH, and Embree's
     // filter asks the pose, the scene that traces, so it still cuts out
     // when the scene that built the BVH is gone.
    GltfQuad q = gltf_fixture::gltf_quad();
    rig(&q);
    const unsigned char px[] = {200, 10, 10, 0, 10, 200, 10, 255};
    gltf_fixture::write_bytes(dir.path / "leaf.png", gltf_fixture::encode_png(px, 2, 1, 4));
    gltf_fixture::use_base_color_image(&q, {{"uri", "leaf.png"}});
    q.doc["materials"][0]["alphaMode"] = "MASK";
    auto loaded = std::make_shared<Scene>(load(dir, "masked.gltf", q), nullptr);
    const std::shared_ptr<const Scene> posed = loaded->at_time(0.5f);
    EXPECT_TRUE(posed->shares_bvh_with(*loaded));
    loaded.reset();
    const Ray kept{Vec3(0.75f, 3, 0.5f), Vec3(0, -1, 0)};
    SurfaceHit hit;
    EXPECT_FALSE(posed->intersect(down, &hit));  // x = 0.25: cut out
    EXPECT_FALSE(posed->occluded(down.o, down.d, 4.0f));
    ASSERT_TRUE(posed->intersect(kept, &hit));
    EXPECT_NEAR(hit.t, 3.0f, 1e-5f);
    EXPECT_TRUE(posed->occluded(kept.o, kept.d, 4.0f));
    // Bare queries with the pose's context (as render_throughput makes them).
    Scene::EmbreeContext ctx = posed->embree_context();
    RTCRay r{0.25f, 3, 0.5f, 0, 0, -1, 0, 0, 4.0f, 0xffffffffu, 0, 0};
    rtcOccluded1(posed->embree_scene(), &ctx.rtc, &r);
    EXPECT_FALSE(r.tfar < 0);
    RTCRay r2{0.75f, 3, 0.5f, 0, 0, -1, 0, 0, 4.0f, 0xffffffffu, 0, 0};
    rtcOccluded1(posed->embree_scene(), &ctx.rtc, &r2);
    EXPECT_TRUE(r2.tfar < 0);
  }
}

// Appends `bytes` as an accessor of `count` elements of `type` and
// `component` (a glTF componentType); returns its index.
size_t add_accessor(GltfQuad* q, const std::string& bytes, size_t count, const char* type,
                    int component) {
  while (q->bin.size() % 4) q->bin += '\0';
  const size_t at = q->bin.size();
  q->bin += bytes;
  q->doc["bufferViews"].push_back(
      {{"buffer", 0}, {"byteOffset", at}, {"byteLength", bytes.size()}});
  q->doc["accessors"].push_back({{"bufferView", q->doc["bufferViews"].size() - 1},
                                 {"componentType", component},
                                 {"count", count},
                                 {"type", type}});
  return q->doc["accessors"].size() - 1;
}

TEST(SceneMotion, ASkinFollowsItsJoints) {
  // The quad skinned to two joints: "hip" at the origin and its child
  // "knee" at (1, 0, 0), which turns 90 degrees about x over the first
  // second. Vertices 0 and 1 follow the hip, 3 the knee, 2 both (weights
  // 0.3 and 0.3, which the loader makes 0.5 each). The quad's own node
  // stands at (5, 5, 5), which a skinned mesh ignores (glTF 3.7.3).
  TempDir dir("motion_skin");
  GltfQuad q = gltf_fixture::gltf_quad();
  q.doc["nodes"][0]["translation"] = {5, 5, 5};
  q.doc["nodes"][0]["skin"] = 0;
  q.doc["nodes"].push_back(Json::parse(R"({"name": "hip", "children": [2]})"));
  q.doc["nodes"].push_back(Json::parse(R"({"name": "knee", "translation": [1, 0, 0]})"));
  q.doc["scenes"][0]["nodes"] = {0, 1};
  const uint16_t joints[16] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0};
  q.doc["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"] = add_accessor(
      &q, std::string(reinterpret_cast<const char*>(joints), sizeof joints), 4, "VEC4", 5123);
  q.doc["meshes"][0]["primitives"][0]["attributes"]["WEIGHTS_0"] = add_accessor(
      &q, floats_bytes({1, 0, 0, 0, 1, 0, 0, 0, 0.3f, 0.3f, 0, 0, 1, 0, 0, 0}), 4, "VEC4", 5126);
  // Inverse bind matrices (column-major): the hip's identity, the knee's
  // translation by (-1, 0, 0).
  const size_t ibm =
      add_accessor(&q, floats_bytes({1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0,  0, 0, 1,  //
                                     1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, -1, 0, 0, 1}),
                   2, "MAT4", 5126);
  q.doc["skins"] = {{{"joints", {1, 2}}, {"inverseBindMatrices", ibm}}};
  const float h = std::sqrt(0.5f);
  add_channel(&q, 2, "rotation", {0, 1}, {0, 0, 0, 1, h, 0, 0, h});
  SceneData s = load(dir, "skin.gltf", q);
  ASSERT_NE(s.motion, nullptr);
  ASSERT_EQ(s.motion->skins.size(), 1u);
  // The vertices as the loader leaves them may be in any order (assimp
  // joins and reorders); find each by its position in the bind pose.
  SceneData bind = pose(s, 0.0f);
  SceneData bent = pose(s, 1.0f);
  ASSERT_EQ(bind.positions.size(), 4u);
  int found = 0;
  for (size_t v = 0; v < 4; ++v) {
    const Vec3 p = bind.positions[v];
    Vec3 expected = p;  // the hip's vertices stay
    if (length(p - Vec3(1, 0, 1)) < 1e-5f) {
      // Half the hip's (1, 0, 1) and half the knee's: (0, 0, 1) from the
      // knee turned to (0, -1, 0), back at (1, -1, 0).
      expected = Vec3(1, -0.5f, 0.5f);
      ++found;
    } else if (length(p - Vec3(1, 0, 0)) < 1e-5f) {
      expected = Vec3(1, 0, 0);  // on the knee's axis
      ++found;
    } else {
      EXPECT_NEAR(p.x, 0.0f, 1e-5f) << "vertex " << v;  // not moved by (5, 5, 5)
      EXPECT_NEAR(p.y, 0.0f, 1e-5f) << "vertex " << v;
    }
    expect_near3(bent.positions[v], expected, 1e-5f);
  }
  EXPECT_EQ(found, 2);
  // Halfway (45 degrees): the knee-only vertex 3 is on the axis; vertex 2
  // is the mean of (1, 0, 1) and (1, -sin 45, cos 45).
  SceneData half = pose(s, 0.5f);
  for (size_t v = 0; v < 4; ++v)
    if (length(bind.positions[v] - Vec3(1, 0, 1)) < 1e-5f)
      expect_near3(half.positions[v], Vec3(1, -0.5f * h, 0.5f * (1 + h)), 1e-5f);
}

TEST(SceneMotion, CubicSplinesFollowTheirTangents) {
  // Translation from (0, 0, 0) to (1, 0, 0) over 2 s, leaving upwards at
  // 3 per second and arriving from above at -3 per second: halfway (t = 1,
  // s = 0.5) the Hermite basis weighs the values 1/2 each and the tangents
  // +-1/8 times the span, 2 s: (0.5, 0.75 + 0.75, 0). Linear would be (0.5, 0, 0).
  TempDir dir("motion_cubic");
  GltfQuad q = quad_on_rig();
  add_channel(&q, 1, "translation", {0, 2},
              {0, 0, 0, 0, 0, 0, 0, 3, 0,  //
               0, -3, 0, 1, 0, 0, 0, 0, 0},
              "CUBICSPLINE");
  SceneData s = load_without_warnings(dir, "cubic.gltf", q);
  ASSERT_NE(s.motion, nullptr);
  expect_near3(pose(s, 0.0f).positions[0], Vec3(0, 0, 0), 1e-6f);
  expect_near3(pose(s, 1.0f).positions[0], Vec3(0.5f, 1.5f, 0), 1e-5f);
  expect_near3(pose(s, 2.0f).positions[0], Vec3(1, 0, 0), 1e-6f);
  // A quarter of the way: h00 = 27/32, h10 = 9/64, h01 = 5/32, h11 = -3/64.
  expect_near3(pose(s, 0.5f).positions[0], Vec3(5.0f / 32, 2 * (27.0f / 64 + 9.0f / 64), 0), 1e-5f);
}

// The quad with one morph target that lifts vertex 2, (1, 0, 1), by
// (0, 1, 0), at the default weight `weight` (Blender: a shape key's value).
GltfQuad quad_with_lift(float weight) {
  GltfQuad q = gltf_fixture::gltf_quad();
  const size_t lift =
      add_accessor(&q, floats_bytes({0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0}), 4, "VEC3", 5126);
  q.doc["accessors"][lift]["min"] = {0, 0, 0};
  q.doc["accessors"][lift]["max"] = {0, 1, 0};
  q.doc["meshes"][0]["primitives"][0]["targets"] = {{{"POSITION", lift}}};
  q.doc["meshes"][0]["weights"] = {weight};
  return q;
}

TEST(SceneMotion, MorphTargetsTakeTheirWeights) {
  TempDir dir("motion_morph");
  GltfQuad q = quad_with_lift(0.25f);
  SceneData still = load(dir, "still.gltf", q);
  EXPECT_EQ(still.motion, nullptr);  // static weights are applied at load
  expect_near3(still.positions[2], Vec3(1, 0.25f, 1), 1e-6f);
  expect_near3(still.positions[0], Vec3(0, 0, 0), 1e-6f);
  // Animated weights 0 -> 1 over the first second (Blender: a keyed shape key).
  add_channel(&q, 0, "weights", {0, 1}, {0, 1});
  SceneData moving = load(dir, "moving.gltf", q);
  ASSERT_NE(moving.motion, nullptr);
  ASSERT_EQ(moving.motion->morphs.size(), 1u);
  expect_near3(moving.positions[2], Vec3(1, 0.25f, 1), 1e-6f);  // as loaded: the default weight
  expect_near3(pose(moving, 0.0f).positions[2], Vec3(1, 0, 1), 1e-6f);
  expect_near3(pose(moving, 0.5f).positions[2], Vec3(1, 0.5f, 1), 1e-6f);
  expect_near3(pose(moving, 2.0f).positions[2], Vec3(1, 1, 1), 1e-6f);
  expect_near3(pose(moving, 0.5f).positions[1], Vec3(0, 0, 1), 1e-6f);  // no offset there
}

TEST(SceneMotion, MorphWeightsFollowStepAndCubicSamplers) {
  // The lift, its weight driven 0 -> 1.
  TempDir dir("motion_morph_samplers");
  const GltfQuad q = quad_with_lift(0.0f);
  // STEP: the weight stays 0 until the key at 1 s.
  GltfQuad step = q;
  add_channel(&step, 0, "weights", {0, 1}, {0, 1}, "STEP");
  SceneData held = load(dir, "step.gltf", step);
  ASSERT_NE(held.motion, nullptr);
  expect_near3(pose(held, 0.5f).positions[2], Vec3(1, 0, 1), 1e-6f);
  expect_near3(pose(held, 0.999f).positions[2], Vec3(1, 0, 1), 1e-6f);
  expect_near3(pose(held, 1.0f).positions[2], Vec3(1, 1, 1), 1e-6f);
  // CUBICSPLINE over 2 s, leaving at +3 per second and arriving at -3 per
  // second: halfway the Hermite basis gives 0.5 + 2 (3 / 8) + 2 (3 / 8) =
  // 2 (linear would be 0.5); a quarter of the way 5/32 + 2 (9/64) 3 +
  // 2 (-3/64)(-3) = 41/32.
  GltfQuad cubic = q;
  add_channel(&cubic, 0, "weights", {0, 2}, {0, 0, 3, -3, 1, 0}, "CUBICSPLINE");
  SceneData spline = load_without_warnings(dir, "cubic.gltf", cubic);
  ASSERT_NE(spline.motion, nullptr);
  expect_near3(pose(spline, 0.0f).positions[2], Vec3(1, 0, 1), 1e-6f);
  expect_near3(pose(spline, 1.0f).positions[2], Vec3(1, 2, 1), 1e-5f);
  expect_near3(pose(spline, 0.5f).positions[2], Vec3(1, 41.0f / 32, 1), 1e-5f);
  expect_near3(pose(spline, 2.0f).positions[2], Vec3(1, 1, 1), 1e-6f);
}

// The file's TANGENT moves with a moving mesh (rotated, and its sign w
// turned where the transform comes to mirror), where computing the
// tangent again from the texture coordinates would give another one.
TEST(SceneMotion, TheFilesTangentsMoveWithTheMesh) {
  TempDir dir("motion_tangent");
  auto with_normal_map = [&](GltfQuad q) {
    gltf_fixture::add_attribute(&q, "TANGENT", {0, 0, 1, 1});
    gltf_fixture::add_attribute(&q, "NORMAL", {0, 1, 0});
    const unsigned char px[] = {128, 128, 255};
    gltf_fixture::write_bytes(dir.path / "n.png", gltf_fixture::encode_png(px, 1, 1, 3));
    q.doc["images"] = Json::array({{{"uri", "n.png"}}});
    q.doc["textures"] = Json::parse(R"([{"source": 0}])");
    q.doc["materials"][0]["normalTexture"] = {{"index", 0}};
    return q;
  };
  // A quarter turn about y over 2 s: +z turns to +x (u grows along +x, so
  // a computed tangent would turn from +x to -z).
  GltfQuad turning = with_normal_map(quad_on_rig());
  add_channel(&turning, 1, "rotation", {0, 2},
              {0, 0, 0, 1, 0, std::sqrt(0.5f), 0, std::sqrt(0.5f)});
  SceneData s = load(dir, "turning.gltf", turning);
  ASSERT_NE(s.motion, nullptr);
  ASSERT_EQ(s.tangents.size(), s.positions.size());
  for (const SceneData::Tangent& t : s.tangents) {
    expect_near3(t.t, Vec3(0, 0, 1), 1e-6f);
    EXPECT_EQ(t.w, 1.0f);
  }
  const float h = std::sqrt(0.5f);
  for (const auto& [time, expected] : {std::pair{1.0f, Vec3(h, 0, h)}, {2.0f, Vec3(1, 0, 0)}}) {
    SceneData p = pose(s, time);
    ASSERT_EQ(p.tangents.size(), p.positions.size());
    for (const SceneData::Tangent& t : p.tangents) {
      expect_near3(t.t, expected, 1e-5f);
      EXPECT_EQ(t.w, 1.0f) << "t = " << time;
    }
  }
  // Scale x 1 -> -1 over 1 s: the tangent stays +z, the bitangent
  // (cross(n, t) w = +x in the mesh) is mirrored to -x while cross(n, t)
  // stays +x, so w turns to -1.
  GltfQuad mirroring = with_normal_map(quad_on_rig());
  add_channel(&mirroring, 1, "scale", {0, 1}, {1, 1, 1, -1, 1, 1});
  SceneData m = load(dir, "mirroring.gltf", mirroring);
  ASSERT_NE(m.motion, nullptr);
  for (const SceneData::Tangent& t : pose(m, 1.0f).tangents) {
    expect_near3(t.t, Vec3(0, 0, 1), 1e-6f);
    EXPECT_EQ(t.w, -1.0f);
  }
  for (const SceneData::Tangent& t : pose(m, 0.25f).tangents) EXPECT_EQ(t.w, 1.0f);
}

TEST(SceneMotion, BadKeysAreLoadErrorsNamingTheNode) {
  TempDir dir("motion_bad");
  // Key times that go back, and a rotation key of length 0.
  GltfQuad back = quad_on_rig();
  add_channel(&back, 1, "translation", {1, 0.5f}, {0, 0, 0, 0, 1, 0});
  GltfQuad zero = quad_on_rig();
  add_channel(&zero, 1, "rotation", {0, 1}, {0, 0, 0, 1, 0, 0, 0, 0});
  for (auto [name, q, why] : {std::tuple{"back.gltf", back, "not finite and increasing"},
                              std::tuple{"zero.gltf", zero, "not a rotation"}}) {
    try {
      load(dir, name, q);
      ADD_FAILURE() << name << ": loaded";
    } catch (const SpecError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(name), std::string::npos) << what;
      EXPECT_NE(what.find("node \"rig\""), std::string::npos) << what;
      EXPECT_NE(what.find(why), std::string::npos) << what;
    }
  }
}

TEST(SceneMotion, TheCameraHoldsStillOnAStepTrack) {
  // The camera's node jumps from (0, 5, 0) to (0, 9, 0) at t = 1 (STEP): the
  // frames before the key (fps 24: frame 23 is 0.958 s) see the first
  // position, not a glide towards the second.
  TempDir dir("motion_camera");
  GltfQuad q = gltf_fixture::gltf_quad();
  q.doc["cameras"] = Json::parse(R"([{"type": "perspective",
                                      "perspective": {"yfov": 0.5, "znear": 0.1}}])");
  q.doc["nodes"].push_back(Json::parse(R"({"name": "cam", "camera": 0, "translation": [0, 5, 0],
      "rotation": [-0.7071068, 0, 0, 0.7071068]})"));
  q.doc["scenes"][0]["nodes"] = {0, 1};
  add_channel(&q, 1, "translation", {0, 1}, {0, 5, 0, 0, 9, 0}, "STEP");
  SceneData s = load(dir, "camera.gltf", q);
  EXPECT_EQ(s.motion, nullptr);  // only the camera moves
  JobSpec spec = testing::make_spec(8, 8, Vec3(0.0f), Vec3(0, 0, -1));
  spec.camera_from_scene = true;
  spec.fps = 24;
  spec.frame_end = 30;
  for (int frame : {0, 12, 23}) {
    const CameraState c = camera_for_frame(spec, s, frame);
    EXPECT_NEAR(c.position[1], 5.0f, 1e-5f) << "frame " << frame;
  }
  for (int frame : {24, 30}) {
    const CameraState c = camera_for_frame(spec, s, frame);
    EXPECT_NEAR(c.position[1], 9.0f, 1e-5f) << "frame " << frame;
  }
  // LINEAR: frame 12 is halfway.
  GltfQuad linear = q;
  linear.doc["animations"][0]["samplers"][0]["interpolation"] = "LINEAR";
  EXPECT_NEAR(camera_for_frame(spec, load(dir, "linear.gltf", linear), 12).position[1], 7.0f,
              1e-5f);
}

// The scene camera is posed at each frame's time by its node's samplers,
// not interpolated between key poses: on a CUBICSPLINE between keys, and
// under a parent that turns (LINEAR keys), where a straight line between
// the key positions would cut the arc the camera flies.
TEST(SceneMotion, TheCameraIsPosedExactlyAtEachFramesTime) {
  TempDir dir("motion_camera_exact");
  GltfQuad q = gltf_fixture::gltf_quad();
  q.doc["cameras"] = Json::parse(R"([{"type": "perspective",
                                      "perspective": {"yfov": 0.5, "znear": 0.1}}])");
  q.doc["nodes"].push_back(
      Json::parse(R"({"name": "cam", "camera": 0, "translation": [0, 0, 2]})"));
  q.doc["nodes"].push_back(Json::parse(R"({"name": "boom", "children": [1]})"));
  q.doc["scenes"][0]["nodes"] = {0, 2};
  JobSpec spec = testing::make_spec(8, 8, Vec3(0.0f), Vec3(0, 0, -1));
  spec.camera_from_scene = true;
  spec.fps = 10;
  spec.frame_end = 20;
  // The boom turns a quarter about y over 1 s: at 0.5 s (frame 5) the
  // camera is 45 degrees round its arc of radius 2.
  GltfQuad turning = q;
  add_channel(&turning, 2, "rotation", {0, 1},
              {0, 0, 0, 1, 0, std::sqrt(0.5f), 0, std::sqrt(0.5f)});
  const CameraState arc = camera_for_frame(spec, load(dir, "turning.gltf", turning), 5);
  const float r = 2 * std::sqrt(0.5f);
  EXPECT_NEAR(arc.position[0], r, 1e-5f);
  EXPECT_NEAR(arc.position[1], 0.0f, 1e-6f);
  EXPECT_NEAR(arc.position[2], r, 1e-5f);
  // The camera's own CUBICSPLINE from (0, 0, 2) to (1, 0, 2) over 2 s,
  // leaving upwards at 3 per second and arriving from above (the spline of
  // CubicSplinesFollowTheirTangents): at 0.3 s (frame 3), w = 0.15, the
  // Hermite basis gives x = h01 and y = 2 (3 h10 - 3 h11).
  GltfQuad spline = q;
  add_channel(&spline, 1, "translation", {0, 2},
              {0, 0, 0, 0, 0, 2, 0, 3, 0,  //
               0, -3, 0, 1, 0, 2, 0, 0, 0},
              "CUBICSPLINE");
  const CameraState c = camera_for_frame(spec, load(dir, "spline.gltf", spline), 3);
  const float w = 0.15f, h10 = w * w * w - 2 * w * w + w, h01 = -2 * w * w * w + 3 * w * w,
              h11 = w * w * w - w * w;
  EXPECT_NEAR(c.position[0], h01, 1e-6f);
  EXPECT_NEAR(c.position[1], 2 * (3 * h10 - 3 * h11), 1e-5f);
  EXPECT_NEAR(c.position[2], 2.0f, 1e-6f);
}

// Keys that are finite can still make a spline overflow between them: the
// camera of such a frame is an error naming the camera and the frame, not
// a frame rendered from infinity (job_resolve checks every frame of a job
// with camera.from_scene this way before it is submitted).
TEST(SceneMotion, ACameraSplineThatOverflowsIsAnErrorAtItsFrame) {
  TempDir dir("motion_camera_overflow");
  GltfQuad q = gltf_fixture::gltf_quad();
  q.doc["cameras"] = Json::parse(R"([{"type": "perspective",
                                      "perspective": {"yfov": 0.5, "znear": 0.1}}])");
  q.doc["nodes"].push_back(Json::parse(R"({"name": "cam", "camera": 0})"));
  q.doc["scenes"][0]["nodes"] = {0, 1};
  add_channel(&q, 1, "translation", {0, 2},
              {0, 0, 0, 3e38f, 0, 0, 3e38f, 0, 0,  //
               -3e38f, 0, 0, 3e38f, 0, 0, 0, 0, 0},
              "CUBICSPLINE");
  const SceneData s = load(dir, "overflow.gltf", q);  // every key is finite
  JobSpec spec = testing::make_spec(8, 8, Vec3(0.0f), Vec3(0, 0, -1));
  spec.camera_from_scene = true;
  spec.camera_keys.clear();
  spec.fps = 1;
  spec.frame_end = 2;
  EXPECT_NO_THROW(camera_for_frame(spec, s, 0));
  try {
    camera_for_frame(spec, s, 1);
    FAIL() << "a camera at infinity was accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "camera.from_scene");
    EXPECT_NE(std::string(e.what()).find("non-finite"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("frame 1"), std::string::npos) << e.what();
  }
}

// The scene camera's clipping planes (glTF znear, zfar; Blender's Clip
// Start and End) clip camera rays as Cycles does: two quads 2 and 3 below
// a camera that looks down; znear 2.5 sees through the upper one, zfar
// 1.5 sees neither. A zfar the file leaves out is infinite (assimp 5.2
// would make it 100), and a job with its own camera keys is not clipped.
TEST(SceneMotion, TheSceneCamerasClippingPlanesClipCameraRays) {
  TempDir dir("camera_clip");
  GltfQuad q = gltf_fixture::gltf_quad();
  q.doc["nodes"][0]["translation"] = {-0.5, 0, -0.5};
  q.doc["nodes"].push_back(Json::parse(R"({"mesh": 0, "translation": [-0.5, 1, -0.5]})"));
  q.doc["nodes"].push_back(Json::parse(R"({"name": "cam", "camera": 0, "translation": [0, 3, 0],
      "rotation": [-0.7071068, 0, 0, 0.7071068]})"));
  q.doc["scenes"][0]["nodes"] = {0, 1, 2};
  auto centre_depth = [&](const char* name, const char* perspective, bool from_scene) {
    GltfQuad c = q;
    c.doc["cameras"] =
        Json::array({{{"type", "perspective"}, {"perspective", Json::parse(perspective)}}});
    gltf_fixture::write_gltf(dir.path / name, c);
    JobSpec spec = testing::make_spec(4, 4, Vec3(0, 3, 0), Vec3(0, 0, 0));
    if (from_scene) {
      spec.camera_from_scene = true;
      spec.camera_keys.clear();
    }
    spec.scene = dir.path / name;
    spec.versions = 1;
    spec.reference_spp = 1;
    spec.albedo_ref_spp = 1;
    spec.environment = EnvironmentSpec{};
    spec.environment->color = Vec3(1.0f);
    const auto scene = load_scene(spec);
    RenderOptions options;
    options.threads = 1;
    const FrameBuffers fb = render_frame(*scene, spec, 0, std::nullopt, options);
    return std::pair{fb.depth[size_t(1 * 4 + 1)], scene->data().scene_camera->zfar};
  };
  EXPECT_NEAR(centre_depth("open.gltf", R"({"yfov": 0.3, "znear": 0.1})", true).first, 2.0f, 1e-4f);
  EXPECT_TRUE(std::isinf(centre_depth("open.gltf", R"({"yfov": 0.3, "znear": 0.1})", true).second));
  EXPECT_NEAR(centre_depth("near.gltf", R"({"yfov": 0.3, "znear": 2.5})", true).first, 3.0f, 1e-4f);
  // Nothing between the planes: the environment (depth 0, as any escape).
  EXPECT_EQ(centre_depth("far.gltf", R"({"yfov": 0.3, "znear": 0.1, "zfar": 1.5})", true).first,
            0.0f);
  // The job's own camera: no clipping.
  EXPECT_NEAR(centre_depth("near.gltf", R"({"yfov": 0.3, "znear": 2.5})", false).first, 2.0f,
              1e-4f);
}

// A camera 6 above the quad's centre looking down; the rig lifts the quad
// from y = 0 to y = 4 over the first second.
// Each test names its own folder: ctest runs tests as parallel processes.
struct MovingQuadJob {
  TempDir dir;
  JobSpec spec;
  std::shared_ptr<const Scene> scene;
  explicit MovingQuadJob(const std::string& name) : dir(name) {
    GltfQuad q = gltf_fixture::gltf_quad();
    q.doc["nodes"].push_back(Json::parse(R"({"name": "rig", "children": [0]})"));
    q.doc["scenes"][0]["nodes"] = {1};
    add_channel(&q, 1, "translation", {0, 1}, {0, 0, 0, 0, 4, 0});
    gltf_fixture::write_gltf(dir.path / "moving.gltf", q);
    spec = testing::make_spec(8, 8, Vec3(0.5f, 6, 0.5f), Vec3(0.5f, 0, 0.5f), 5.0f, 1.0f, 0.05f);
    spec.camera_keys[0].focus = FocusMode::kAuto;
    spec.scene = dir.path / "moving.gltf";
    spec.fps = 24;
    spec.frame_end = 24;
    spec.versions = 1;
    spec.reference_spp = 2;
    spec.albedo_ref_spp = 1;
    spec.environment = EnvironmentSpec{};
    spec.environment->color = Vec3(1.0f);
    scene = load_scene(spec);
  }
};

TEST(SceneMotion, EachFrameSeesTheQuadWhereItIsThen) {
  MovingQuadJob job("motion_render_each");
  for (int frame : {0, 6, 12, 24}) {
    const float y = 4.0f * std::min(1.0f, float(frame) / 24.0f);
    RenderOptions options;
    options.threads = 1;
    const FrameBuffers fb = render_frame(*job.scene, job.spec, frame, std::nullopt, options);
    // The depth of the centre pixels (pinhole rays) is the camera's height
    // over the quad at the frame's time, and autofocus follows it, so the
    // quad is in focus (CoC 0) in every frame.
    for (size_t i : {size_t(3 * 8 + 3), size_t(4 * 8 + 4)}) {
      EXPECT_NEAR(fb.depth[i], 6.0f - y, 1e-4f) << "frame " << frame;
      EXPECT_NEAR(fb.coc[i], 0.0f, 1e-3f) << "frame " << frame;
    }
    EXPECT_NEAR(fb.camera.focal_distance, 6.0f - y, 1e-4f) << "frame " << frame;
  }
}

TEST(SceneMotion, AFrameIsTheSameWhicheverFramesCameBefore) {
  // Poses are cached per time: frame 12 rendered first, after frames 0 and
  // 24, and from a freshly loaded scene, byte for byte the same.
  MovingQuadJob job("motion_render_order");
  RenderOptions options;
  options.threads = 2;
  const FrameBuffers first = render_frame(*job.scene, job.spec, 12, std::nullopt, options);
  render_frame(*job.scene, job.spec, 0, std::nullopt, options);
  render_frame(*job.scene, job.spec, 24, std::nullopt, options);
  const FrameBuffers again = render_frame(*job.scene, job.spec, 12, std::nullopt, options);
  const FrameBuffers fresh = render_frame(job.spec, 12, std::nullopt, options);
  EXPECT_TRUE(testing::same_bytes(first, again));
  EXPECT_TRUE(testing::same_bytes(first, fresh));
  // Frames 0 and 12 see the quad at different depths (it moved).
  const FrameBuffers zero = render_frame(*job.scene, job.spec, 0, std::nullopt, options);
  EXPECT_NE(first.depth, zero.depth);
}

TEST(SceneMotion, TilesOfInterleavedFramesPasteIntoTheWholeFrames) {
  // A worker may get the tiles of three frames in turn; with two poses kept,
  // every tile then poses its frame again. Each frame pasted from its four
  // tiles equals the frame rendered whole, byte for byte.
  MovingQuadJob job("motion_render_tiles");
  RenderOptions options;
  options.threads = 2;
  const std::vector<int> frames = {0, 12, 24};
  std::vector<FrameBuffers> pasted(frames.size());
  for (FrameBuffers& f : pasted) {
    f.allocate(job.spec.width, job.spec.height, job.spec.versions);
    f.rect = Rect{0, 0, job.spec.width, job.spec.height};
  }
  for (const Rect& r : {Rect{0, 0, 4, 4}, Rect{4, 0, 4, 4}, Rect{0, 4, 4, 4}, Rect{4, 4, 4, 4}})
    for (size_t i = 0; i < frames.size(); ++i) {
      const FrameBuffers tile = render_frame(*job.scene, job.spec, frames[i], r, options);
      pasted[i].paste(tile);
      pasted[i].camera = tile.camera;
    }
  for (size_t i = 0; i < frames.size(); ++i) {
    const FrameBuffers whole = render_frame(*job.scene, job.spec, frames[i], std::nullopt, options);
    EXPECT_TRUE(testing::same_bytes(pasted[i], whole)) << "frame " << frames[i];
  }
}

}  // namespace
}  // namespace dofarm::render
