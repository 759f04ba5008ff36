// Scene loading (assimp -> SceneData), the bundled scenes as designed in
// jobs/scenes/make_scenes.py, the shape builders and texture lookup.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "common/error.h"
#include "common/exr_io.h"
#include "worker/render/scene_data.h"
#include "worker/render/shapes.h"

namespace dofarm::render {
namespace {

const std::filesystem::path kScenes = std::filesystem::path(DOFARM_SOURCE_DIR) / "jobs" / "scenes";

Vec3 tri_vertex(const SceneData& s, size_t tri, int k) {
  return s.positions[s.indices[tri * 3 + k]];
}
Vec3 tri_cross(const SceneData& s, size_t tri) {
  Vec3 a = tri_vertex(s, tri, 0);
  return cross(tri_vertex(s, tri, 1) - a, tri_vertex(s, tri, 2) - a);
}
Vec3 tri_centroid(const SceneData& s, size_t tri) {
  return (tri_vertex(s, tri, 0) + tri_vertex(s, tri, 1) + tri_vertex(s, tri, 2)) / 3.0f;
}
double total_area(const SceneData& s) {
  double area = 0;
  for (size_t t = 0; t < s.triangle_count(); ++t) area += 0.5 * length(tri_cross(s, t));
  return area;
}
int material_named(const SceneData& s, const std::string& name) {
  for (size_t i = 0; i < s.materials.size(); ++i) {
    if (s.materials[i].name == name) return static_cast<int>(i);
  }
  ADD_FAILURE() << "no material " << name;
  return -1;
}
void expect_near3(Vec3 a, Vec3 b, float tol) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

// --- Cornell box -------------------------------------------------------------

class CornellScene : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new SceneData(load_scene_data(kScenes / "cornell.gltf"));
  }
  static void TearDownTestSuite() { delete scene_; }
  static SceneData* scene_;
};
SceneData* CornellScene::scene_ = nullptr;

TEST_F(CornellScene, TriangleCountAsGenerated) {
  // 5 walls and the light (2 each), two boxes without bottoms (5 faces x 2),
  // two icospheres of 3 subdivisions (20 * 4^3).
  EXPECT_EQ(scene_->triangle_count(), 5 * 2 + 2 + 2 * 10 + 2 * 1280);
  EXPECT_EQ(scene_->indices.size(), 3 * scene_->triangle_count());
  EXPECT_EQ(scene_->normals.size(), scene_->positions.size());
  EXPECT_TRUE(scene_->camera_track.empty());  // the job spec keys the camera
}

TEST_F(CornellScene, WorldBoundsAreTheTwoUnitBox) {
  Vec3 lo(1e30f), hi(-1e30f);
  for (Vec3 p : scene_->positions) {
    lo = vmin(lo, p);
    hi = vmax(hi, p);
  }
  expect_near3(lo, Vec3(-1, 0, -1), 1e-6f);
  expect_near3(hi, Vec3(1, 2, 1), 1e-6f);
}

TEST_F(CornellScene, NormalsAreUnit) {
  for (Vec3 n : scene_->normals) ASSERT_NEAR(length(n), 1.0f, 1e-4f);
}

TEST_F(CornellScene, MaterialsAsDesigned) {
  const auto& m = scene_->materials;
  const Material& light = m[material_named(*scene_, "light")];
  // KHR_materials_emissive_strength 17 times emissiveFactor (1, 12/17, 4/17).
  expect_near3(light.emission, Vec3(17, 12, 4), 1e-4f);
  expect_near3(m[material_named(*scene_, "red")].base_color, Vec3(0.65f, 0.05f, 0.05f), 1e-6f);
  expect_near3(m[material_named(*scene_, "green")].base_color, Vec3(0.12f, 0.45f, 0.15f), 1e-6f);
  expect_near3(m[material_named(*scene_, "white")].base_color, Vec3(0.73f), 1e-6f);
  EXPECT_FALSE(m[material_named(*scene_, "white")].is_emissive());
  const Material& metal = m[material_named(*scene_, "glossy_metal")];
  EXPECT_FLOAT_EQ(metal.metallic, 1.0f);
  EXPECT_FLOAT_EQ(metal.roughness, 0.2f);
  const Material& dielectric = m[material_named(*scene_, "rough_dielectric")];
  EXPECT_FLOAT_EQ(dielectric.metallic, 0.0f);
  EXPECT_FLOAT_EQ(dielectric.roughness, 0.35f);
  EXPECT_FLOAT_EQ(dielectric.ior, 1.46f);  // KHR_materials_ior, not the default 1.5
  for (const Material& mat : m) EXPECT_FALSE(mat.has_textures());
}

TEST_F(CornellScene, WallsHaveTheirColoursAndLightFacesDown) {
  const auto red = static_cast<uint32_t>(material_named(*scene_, "red"));
  const auto green = static_cast<uint32_t>(material_named(*scene_, "green"));
  const auto light = static_cast<uint32_t>(material_named(*scene_, "light"));
  int red_tris = 0, green_tris = 0, light_tris = 0;
  for (size_t t = 0; t < scene_->triangle_count(); ++t) {
    Vec3 c = tri_centroid(*scene_, t);
    Vec3 ng = normalize(tri_cross(*scene_, t));
    uint32_t mat = scene_->tri_material[t];
    if (mat == red) {
      ++red_tris;
      EXPECT_NEAR(c.x, -1.0f, 1e-6f);
      expect_near3(ng, Vec3(1, 0, 0), 1e-6f);  // faces into the box
    }
    if (mat == green) {
      ++green_tris;
      EXPECT_NEAR(c.x, 1.0f, 1e-6f);
      expect_near3(ng, Vec3(-1, 0, 0), 1e-6f);
    }
    if (mat == light) {
      ++light_tris;
      EXPECT_GT(c.y, 1.99f);
      expect_near3(ng, Vec3(0, -1, 0), 1e-6f);
      for (int k = 0; k < 3; ++k) {
        expect_near3(scene_->normals[scene_->indices[t * 3 + k]], Vec3(0, -1, 0), 1e-6f);
      }
    }
  }
  EXPECT_EQ(red_tris, 2);
  EXPECT_EQ(green_tris, 2);
  EXPECT_EQ(light_tris, 2);
}

TEST_F(CornellScene, GeometricNormalsAgreeWithShadingNormals) {
  // Winding and normals must agree everywhere (incl. the node-transformed
  // spheres), or the renderer sees back faces where there are none.
  for (size_t t = 0; t < scene_->triangle_count(); ++t) {
    Vec3 ng = tri_cross(*scene_, t);
    for (int k = 0; k < 3; ++k) {
      ASSERT_GT(dot(ng, scene_->normals[scene_->indices[t * 3 + k]]), 0.0f) << "triangle " << t;
    }
  }
}

TEST_F(CornellScene, SpheresArePlacedByTheirNodes) {
  // One unit sphere mesh, scaled 0.25 and moved onto the short box by its node.
  const auto metal = static_cast<uint32_t>(material_named(*scene_, "glossy_metal"));
  const Vec3 center(0.33f, 0.85f, 0.33f);
  for (size_t t = 0; t < scene_->triangle_count(); ++t) {
    if (scene_->tri_material[t] != metal) continue;
    for (int k = 0; k < 3; ++k)
      ASSERT_NEAR(length(tri_vertex(*scene_, t, k) - center), 0.25f, 1e-5f);
  }
}

// --- Courtyard ---------------------------------------------------------------

class CourtyardScene : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new SceneData(load_scene_data(kScenes / "courtyard.gltf"));
  }
  static void TearDownTestSuite() { delete scene_; }
  static SceneData* scene_;
};
SceneData* CourtyardScene::scene_ = nullptr;

TEST_F(CourtyardScene, TexturesLoadOnceWithTheirSizes) {
  ASSERT_EQ(scene_->textures.size(), 2u);  // the two plastics share one map
  const Material& ground = scene_->materials[material_named(*scene_, "ground_tiles")];
  ASSERT_GE(ground.base_color_tex.index, 0);
  const Texture& checker = scene_->textures[ground.base_color_tex.index];
  EXPECT_EQ(checker.width, 64);
  EXPECT_EQ(checker.height, 64);
  // Top-left tile is (200, 190, 170) in sRGB, decoded to linear.
  expect_near3(checker.lookup({0.5f / 64, 0.5f / 64}),
               Vec3(srgb_to_linear(200 / 255.0f), srgb_to_linear(190 / 255.0f),
                    srgb_to_linear(170 / 255.0f)),
               1e-5f);
  const Material& red = scene_->materials[material_named(*scene_, "red_plastic")];
  const Material& blue = scene_->materials[material_named(*scene_, "blue_plastic")];
  ASSERT_GE(red.metal_rough_tex.index, 0);
  EXPECT_EQ(red.metal_rough_tex.index, blue.metal_rough_tex.index);
  const Texture& mr = scene_->textures[red.metal_rough_tex.index];
  EXPECT_EQ(mr.width, 32);
  EXPECT_EQ(mr.height, 16);
  // Linear data (not sRGB): G = roughness 0.25 at x = 0, B = metallic 0.
  Vec3 texel = mr.lookup({0.5f / 32, 0.5f / 16});
  EXPECT_NEAR(texel.y, 64 / 255.0f, 1e-6f);
  EXPECT_EQ(texel.z, 0.0f);
  EXPECT_EQ(red.base_color_tex.index, -1);
  EXPECT_EQ(ground.metal_rough_tex.index, -1);
}

TEST_F(CourtyardScene, MaterialsAsDesigned) {
  const auto& m = scene_->materials;
  const Material& brushed = m[material_named(*scene_, "brushed_metal")];
  EXPECT_FLOAT_EQ(brushed.metallic, 1.0f);
  EXPECT_FLOAT_EQ(brushed.roughness, 0.3f);
  EXPECT_FLOAT_EQ(m[material_named(*scene_, "polished_metal")].roughness, 0.05f);
  expect_near3(m[material_named(*scene_, "lamp")].emission, Vec3(20, 12, 6), 1e-4f);
}

TEST_F(CourtyardScene, UvsKeepTheGltfConvention) {
  // The ground's corner (-15, 0, 15) has uv (0, 15) in the file.
  bool found = false;
  for (size_t i = 0; i < scene_->positions.size(); ++i) {
    if (length(scene_->positions[i] - Vec3(-15, 0, 15)) < 1e-5f) {
      EXPECT_NEAR(scene_->uvs[i].x, 0.0f, 1e-6f);
      EXPECT_NEAR(scene_->uvs[i].y, 15.0f, 1e-5f);
      found = true;
    }
  }
  EXPECT_TRUE(found);
}

TEST_F(CourtyardScene, CameraTrackMatchesTheGenerator) {
  // Translation keys at 0, 1, 2 s and rotation keys at 0, 0.5, 1.5, 2 s: the
  // track has a key at each time of the union. Positions include the static
  // rig parent's offset (0, 0.2, 0).
  const auto& track = scene_->camera_track;
  ASSERT_EQ(track.size(), 5u);
  const float times[] = {0.0f, 0.5f, 1.0f, 1.5f, 2.0f};
  for (size_t i = 0; i < 5; ++i) EXPECT_NEAR(track[i].time, times[i], 1e-6f);
  expect_near3(track[0].position, Vec3(0.0f, 1.2f, 6.0f), 1e-5f);
  expect_near3(track[4].position, Vec3(1.8f, 0.9f, 3.2f), 1e-5f);
  // Halfway between the translation keys (0, 1, 6) and (1, 0.8, 4.5).
  expect_near3(track[1].position, Vec3(0.5f, 1.1f, 5.25f), 1e-5f);
  for (const auto& key : track) EXPECT_NEAR(key.yfov_deg, 45.0f, 1e-3f);
  // The camera looks down -z towards its targets (world space, with the rig):
  // (0, 0.8, -1) at the start and (-0.6, 0.8, -3) at the end.
  expect_near3(track[0].rotation.rotate(Vec3(0, 0, -1)),
               normalize(Vec3(0, 0.8f, -1) - track[0].position), 1e-4f);
  expect_near3(track[4].rotation.rotate(Vec3(0, 0, -1)),
               normalize(Vec3(-0.6f, 0.8f, -3) - track[4].position), 1e-4f);
  expect_near3(track[0].rotation.rotate(Vec3(1, 0, 0)) * Vec3(0, 1, 0), Vec3(0.0f), 1e-5f);
}

// --- test scenes and errors --------------------------------------------------

TEST(LoadSceneData, KeepsDegenerateTriangles) {
  SceneData s = load_scene_data(kScenes / "test" / "degenerate.gltf");
  // A quad (2) plus a collinear, a repeated-index and a sliver triangle.
  EXPECT_EQ(s.triangle_count(), 5u);
  EXPECT_NEAR(total_area(s), 4.0, 1e-5);
}

TEST(LoadSceneData, MissingFileNamesTheFile) {
  const auto path = kScenes / "does_not_exist.gltf";
  try {
    load_scene_data(path);
    FAIL() << "expected SpecError";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
    EXPECT_EQ(e.loc().file, path.string());
  }
}

TEST(LoadSceneData, UnreadableFileNamesTheFile) {
  // A job spec is not a scene: assimp's reason is passed on.
  const auto path = std::filesystem::path(DOFARM_SOURCE_DIR) / "jobs" / "cornell.toml";
  try {
    load_scene_data(path);
    FAIL() << "expected SpecError";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("cornell.toml"), std::string::npos) << e.what();
  }
}

TEST(LoadSceneData, NoTrianglesIsAnError) {
  try {
    load_scene_data(kScenes / "test" / "no_triangles.gltf");
    FAIL() << "expected SpecError";
  } catch (const SpecError& e) {
    std::string what = e.what();
    EXPECT_NE(what.find("no_triangles.gltf"), std::string::npos) << what;
    EXPECT_NE(what.find("no triangles"), std::string::npos) << what;
  }
}

TEST(LoadSceneData, NanVertexIsAnError) {
  try {
    load_scene_data(kScenes / "test" / "nan_vertex.gltf");
    FAIL() << "expected SpecError";
  } catch (const SpecError& e) {
    std::string what = e.what();
    EXPECT_NE(what.find("nan_vertex.gltf"), std::string::npos) << what;
    EXPECT_NE(what.find("not finite"), std::string::npos) << what;
  }
}

TEST(LoadSceneData, ObjMaterialsMapOntoMetallicRoughness) {
  // An OBJ without normals: Kd is the base colour, Ns maps to roughness
  // through alpha = sqrt(2 / (Ns + 2)), Ke is the emission, and smooth normals
  // are generated.
  const auto dir = std::filesystem::temp_directory_path() / "dofarm_test_scene_data_obj";
  std::filesystem::create_directories(dir);
  {
    std::ofstream mtl(dir / "quad.mtl");
    mtl << "newmtl lamp\nKd 0.2 0.4 0.6\nNs 98\nKe 5 4 3\n";
    std::ofstream obj(dir / "quad.obj");
    obj << "mtllib quad.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl lamp\nf 1 2 3 4\n";
  }
  SceneData s = load_scene_data(dir / "quad.obj");
  std::filesystem::remove_all(dir);
  ASSERT_EQ(s.triangle_count(), 2u);
  const Material& m = s.materials[s.tri_material[0]];
  expect_near3(m.base_color, Vec3(0.2f, 0.4f, 0.6f), 1e-6f);
  EXPECT_NEAR(m.roughness, std::sqrt(std::sqrt(2.0f / 100.0f)), 1e-6f);
  expect_near3(m.emission, Vec3(5, 4, 3), 1e-6f);
  EXPECT_FLOAT_EQ(m.metallic, 0.0f);
  for (Vec3 n : s.normals) expect_near3(n, Vec3(0, 0, 1), 1e-6f);
}

TEST(LoadSceneData, LightBoxIsClosedWithInwardNormals) {
  SceneData s = load_scene_data(kScenes / "test" / "light_box.gltf");
  EXPECT_EQ(s.triangle_count(), 12u + 2u);
  for (size_t t = 0; t < s.triangle_count(); ++t) {
    if (s.materials[s.tri_material[t]].is_emissive()) continue;
    EXPECT_LT(dot(tri_cross(s, t), tri_centroid(s, t)), 0.0f) << "wall triangle " << t;
  }
}

// --- shapes ------------------------------------------------------------------

TEST(Shapes, IcosphereAreaConvergesToSphere) {
  const float r = 1.5f;
  const double exact = 4.0 * M_PI * r * r;
  double previous_error = 1e30;
  for (int sub = 0; sub <= 5; ++sub) {
    SceneData s;
    add_icosphere(s, Vec3(1, 2, 3), r, sub, Material{});
    EXPECT_EQ(s.triangle_count(), 20u << (2 * sub));
    double error = exact - total_area(s);  // inscribed: always below the sphere
    EXPECT_GT(error, 0.0);
    EXPECT_LT(error, previous_error);
    previous_error = error;
  }
  EXPECT_LT(previous_error / exact, 2e-3);
}

TEST(Shapes, IcosphereNormalsPointOutward) {
  for (bool smooth : {true, false}) {
    SceneData s;
    const Vec3 c(1, 2, 3);
    add_icosphere(s, c, 0.5f, 2, Material{}, smooth);
    for (size_t t = 0; t < s.triangle_count(); ++t) {
      Vec3 out = tri_centroid(s, t) - c;
      ASSERT_GT(dot(tri_cross(s, t), out), 0.0f);
      for (int k = 0; k < 3; ++k) {
        Vec3 n = s.normals[s.indices[t * 3 + k]];
        ASSERT_NEAR(length(n), 1.0f, 1e-5f);
        ASSERT_GT(dot(n, out), 0.0f);
      }
    }
  }
}

TEST(Shapes, BoxNormalsFaceAsAsked) {
  const Vec3 lo(-1, 0, 2), hi(2, 1, 4);
  const Vec3 mid = (lo + hi) * 0.5f;
  for (Facing facing : {Facing::kOutward, Facing::kInward}) {
    SceneData s;
    add_box(s, lo, hi, Material{}, facing);
    ASSERT_EQ(s.triangle_count(), 12u);
    EXPECT_NEAR(total_area(s), 2.0 * (3 * 1 + 1 * 2 + 3 * 2), 1e-5);
    const float sign = facing == Facing::kOutward ? 1.0f : -1.0f;
    for (size_t t = 0; t < 12; ++t) {
      Vec3 ng = normalize(tri_cross(s, t));
      EXPECT_GT(sign * dot(ng, tri_centroid(s, t) - mid), 0.0f);
      expect_near3(s.normals[s.indices[t * 3]], ng, 1e-6f);
    }
  }
}

TEST(Shapes, QuadTriangleAndDiskOrientationAndArea) {
  SceneData s;
  add_quad(s, Vec3(0, 1, 0), Vec3(2, 0, 0), Vec3(0, 0, -0.5f), Material{});  // faces +y
  ASSERT_EQ(s.triangle_count(), 2u);
  EXPECT_NEAR(total_area(s), 4.0, 1e-6);
  for (size_t t = 0; t < 2; ++t) expect_near3(normalize(tri_cross(s, t)), Vec3(0, 1, 0), 1e-6f);
  expect_near3(s.normals[0], Vec3(0, 1, 0), 1e-6f);

  SceneData tri;
  add_triangle(tri, Vec3(0, 0, 0), Vec3(0, 0, 2), Vec3(2, 0, 0), Material{});
  expect_near3(tri.normals[0], Vec3(0, 1, 0), 1e-6f);  // cross(b - a, c - a)
  EXPECT_NEAR(total_area(tri), 2.0, 1e-6);

  SceneData disk;
  const int n = 64;
  add_disk(disk, Vec3(1, 1, 1), Vec3(1, 1, 0), 0.5f, n, Material{});
  EXPECT_EQ(disk.triangle_count(), size_t(n));
  EXPECT_NEAR(total_area(disk), 0.5 * n * 0.25 * std::sin(2 * M_PI / n), 1e-5);
  for (size_t t = 0; t < disk.triangle_count(); ++t) {
    expect_near3(normalize(tri_cross(disk, t)), normalize(Vec3(1, 1, 0)), 1e-5f);
  }
}

TEST(Shapes, MixingMeshesWithAndWithoutNormalsKeepsArraysAligned) {
  SceneData s;
  Material red, white;
  red.base_color = Vec3(1, 0, 0);
  s.add_mesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {}, {}, {0, 1, 2}, red);
  add_quad(s, Vec3(0, 0, -1), Vec3(1, 0, 0), Vec3(0, 1, 0), white);
  s.add_mesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {}, {}, {0, 2, 1}, white);
  ASSERT_EQ(s.positions.size(), 10u);
  ASSERT_EQ(s.normals.size(), 10u);
  ASSERT_EQ(s.uvs.size(), 10u);
  // Zero = "use the geometric normal" for the meshes that had none.
  expect_near3(s.normals[0], Vec3(0.0f), 0.0f);
  expect_near3(s.normals[3], Vec3(0, 0, 1), 1e-6f);
  expect_near3(s.normals[9], Vec3(0.0f), 0.0f);
  EXPECT_EQ(s.indices[0 + 9], 7u);  // the third mesh's indices are offset
  EXPECT_EQ(s.tri_material, (std::vector<uint32_t>{0, 1, 1, 2}));
  EXPECT_EQ(s.materials[0].base_color.x, 1.0f);
}

// --- textures ----------------------------------------------------------------

Texture two_by_two() {
  // Row 0 (top): 0, 1; row 1: 2, 3 (all channels alike, red channel + 10).
  Texture t;
  t.width = 2;
  t.height = 2;
  for (float v : {0.0f, 1.0f, 2.0f, 3.0f}) t.rgb.insert(t.rgb.end(), {v + 10, v, v});
  return t;
}

TEST(Texture, BilinearBetweenTexelCentres) {
  Texture t = two_by_two();
  EXPECT_FLOAT_EQ(t.lookup({0.25f, 0.25f}).y, 0.0f);  // texel centre, top-left
  EXPECT_FLOAT_EQ(t.lookup({0.75f, 0.75f}).y, 3.0f);
  EXPECT_FLOAT_EQ(t.lookup({0.75f, 0.25f}).x, 11.0f);
  EXPECT_FLOAT_EQ(t.lookup({0.5f, 0.25f}).y, 0.5f);  // halfway along the top row
  EXPECT_FLOAT_EQ(t.lookup({0.25f, 0.5f}).y, 1.0f);  // halfway down the left column
  EXPECT_FLOAT_EQ(t.lookup({0.5f, 0.5f}).y, 1.5f);   // the mean of all four
  EXPECT_FLOAT_EQ(t.lookup({0.375f, 0.25f}).y, 0.25f);
}

TEST(Texture, RepeatWraps) {
  Texture t = two_by_two();
  // u = 0 lies between the last column (wrapped) and the first one.
  EXPECT_FLOAT_EQ(t.lookup({0.0f, 0.25f}).y, 0.5f);
  EXPECT_FLOAT_EQ(t.lookup({0.0f, 0.0f}).y, 1.5f);
  EXPECT_FLOAT_EQ(t.lookup({1.25f, -0.75f}).y, 0.0f);
  EXPECT_FLOAT_EQ(t.lookup({-3.25f, 7.75f}).y, 3.0f);
  EXPECT_FLOAT_EQ(t.lookup({1000.75f, 0.25f}).y, 1.0f);
  // Just below 1, and a negative u so small that wrapping rounds it to 1:
  // both between the last column and the first, like u = 0.
  EXPECT_NEAR(t.lookup({0x1.fffffep-1f, 0.25f}).y, 0.5f, 1e-6f);
  EXPECT_FLOAT_EQ(t.lookup({-1e-10f, 0.25f}).y, 0.5f);
}

// glTF magFilter NEAREST (Blender's "Closest"): the texel uv lies in, no
// blending, at and between the centres and across the wrap.
TEST(Texture, NearestTakesTheTexelUvLiesIn) {
  Texture t = two_by_two();
  t.sampler.nearest = true;
  EXPECT_FLOAT_EQ(t.lookup({0.25f, 0.25f}).y, 0.0f);
  EXPECT_FLOAT_EQ(t.lookup({0.49f, 0.25f}).y, 0.0f);
  EXPECT_FLOAT_EQ(t.lookup({0.51f, 0.25f}).y, 1.0f);
  EXPECT_FLOAT_EQ(t.lookup({0.5f, 0.5f}).y, 3.0f);  // a corner belongs to the texel after it
  EXPECT_FLOAT_EQ(t.lookup({0.99f, 0.01f}).x, 11.0f);
  EXPECT_FLOAT_EQ(t.lookup({1.01f, 0.01f}).y, 0.0f);  // repeat
  EXPECT_FLOAT_EQ(t.lookup({-0.01f, 0.01f}).y, 1.0f);
}

// CLAMP_TO_EDGE ("Extend"): beyond the outer texel centres the border texel
// holds, in both directions; MIRRORED_REPEAT ("Mirror"): uv reflects at
// every integer.
TEST(Texture, ClampAndMirrorWrap) {
  Texture t = two_by_two();
  t.sampler.wrap_u = TextureWrap::kClamp;
  t.sampler.wrap_v = TextureWrap::kClamp;
  EXPECT_FLOAT_EQ(t.lookup({0.0f, 0.25f}).y, 0.0f);  // repeat would blend in texel 1: 0.5
  EXPECT_FLOAT_EQ(t.lookup({-3.0f, 0.25f}).y, 0.0f);
  EXPECT_FLOAT_EQ(t.lookup({1.0f, 0.25f}).y, 1.0f);
  EXPECT_FLOAT_EQ(t.lookup({7.0f, 5.0f}).y, 3.0f);
  EXPECT_FLOAT_EQ(t.lookup({0.5f, 0.25f}).y, 0.5f);  // inside: bilinear as before
  t.sampler.wrap_u = TextureWrap::kMirror;
  EXPECT_FLOAT_EQ(t.lookup({1.25f, 0.25f}).y, 1.0f);  // = u 0.75
  EXPECT_FLOAT_EQ(t.lookup({1.75f, 0.25f}).y, 0.0f);  // = u 0.25
  EXPECT_FLOAT_EQ(t.lookup({2.25f, 0.25f}).y, 0.0f);  // = u 0.25 again
  EXPECT_FLOAT_EQ(t.lookup({-0.25f, 0.25f}).y, 0.0f);
  EXPECT_FLOAT_EQ(t.lookup({1.0f, 0.25f}).y, 1.0f);  // the mirror line holds the border texel
  // The alpha channel is read the same way.
  t.alpha = {0.0f, 1.0f, 0.0f, 1.0f};
  t.sampler.nearest = true;
  EXPECT_FLOAT_EQ(t.alpha_lookup({1.75f, 0.25f}), 0.0f);
  EXPECT_FLOAT_EQ(t.alpha_lookup({1.25f, 0.25f}), 1.0f);
}

TEST(Texture, EmptyTextureIsWhite) {
  Texture t;
  expect_near3(t.lookup({0.3f, 0.6f}), Vec3(1.0f), 0.0f);
}

}  // namespace
}  // namespace dofarm::render
