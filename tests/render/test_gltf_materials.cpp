// glTF materials as Blender exports them (docs/renderer.md, "glTF
// coverage"): KHR_materials_ior and KHR_materials_specular as written,
// alphaMode MASK and BLEND, and normal maps with computed and given
// tangents; the files are written by the tests.
#include "tests/render/gltf_fixture.h"
#include "tests/render/render_fixtures.h"

namespace dofarm::render {
namespace {

using namespace gltf_fixture;

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
  EXPECT_GE(m.normal_tex.index, 0);
  EXPECT_EQ(s.tangents.size(), s.positions.size());
}

// alphaMode MASK: the cutoff, baseColorFactor's alpha and the base colour
// texture's alpha channel are read (an RGBA PNG, here 2 x 1: alpha 0 and
// 255); an opaque material loads no alpha.
TEST(GltfAlphaMask, MaskReadsCutoffFactorAndTheTexturesAlpha) {
  TempDir dir("alpha_mask");
  const unsigned char px[] = {200, 10, 10, 0, 10, 200, 10, 255};
  write_bytes(dir.path / "leaf.png", encode_png(px, 2, 1, 4));
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
  ASSERT_GE(m.base_color_tex.index, 0);
  const Texture& t = s.textures[size_t(m.base_color_tex.index)];
  ASSERT_EQ(t.alpha.size(), 2u);
  EXPECT_EQ(t.alpha[0], 0.0f);
  EXPECT_EQ(t.alpha[1], 1.0f);
  EXPECT_NEAR(t.rgb[0], srgb_to_linear(200 / 255.0f), 1e-6f);  // colour as before

  q.doc["materials"][0].erase("alphaMode");
  write_gltf(dir.path / "opaque.gltf", q);
  SceneData o = load_scene_data(dir.path / "opaque.gltf");
  EXPECT_FALSE(o.materials[o.tri_material[0]].alpha_mask);
  EXPECT_TRUE(
      o.textures[size_t(o.materials[o.tri_material[0]].base_color_tex.index)].alpha.empty());
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
  leaf.base_color_tex.index = 0;
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
  Scene scene(testing::blend_over_floor(0.3f), std::make_unique<Environment>(Vec3(1.0f)));
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
  return encode_png(px, 1, 1, 3);
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
  EXPECT_EQ(d.materials[d.tri_material[0]].normal_tex.index, -1);
  EXPECT_TRUE(d.tangents.empty());
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
  expect_warnings(log.lines(), {{"\"below\"", "KHR_materials_ior"}});
}

// KHR_materials_specular's factors as written (what Blender 3.4 exports for
// a Principled BSDF whose Specular is not 0.5: specularColorFactor =
// 0.08 specular / F0(ior)); no extension is factor 1 and white; a value
// outside the schema is warned about, naming the material and the key, and
// the default used; a texture the file does not have is named in a warning
// (GltfMaterials.SpecularTexturesScaleTheirFactors reads real ones). The
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
  expect_warnings(log.lines(), {{"\"factor_above\"", "specularFactor 1.5"},
                                {"\"color_negative\"", "specularColorFactor"},
                                {"\"textured\"", "specularTexture names texture 0, which"}});
  expect_extension_read(log.lines());
}

// KHR_materials_transmission's factor as written (what Blender 3.4 exports
// for a Principled BSDF with Transmission > 0, beside KHR_materials_ior); no
// extension or no key is 0; a value outside [0, 1] is warned about, naming
// the material and the key, and 0 used (its texture: the next test). The
// extension is read, so it is not in the "ignores" warning.
TEST(GltfMaterials, TransmissionFactorIsRead) {
  TempDir dir("transmission");
  LogCapture log;
  struct Case {
    const char* name;
    Json ext;  // null: no extension
    float factor;
  } cases[] = {{"glass", {{"transmissionFactor", 1.0}}, 1.0f},
               {"half", {{"transmissionFactor", 0.5}}, 0.5f},
               {"empty", Json::object(), 0.0f},
               {"none", nullptr, 0.0f},
               {"above", {{"transmissionFactor", 1.5}}, 0.0f}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Material m =
        material_with_extension(dir.path, c.name, "KHR_materials_transmission", c.ext);
    EXPECT_FLOAT_EQ(m.transmission, c.factor);
  }
  expect_warnings(log.lines(), {{"\"above\"", "transmissionFactor 1.5"}});
  expect_extension_read(log.lines());
}

// KHR_materials_clearcoat's clearcoatNormalTexture bends the coat's normal
// (SurfaceHit::coat_ns) in the tangent frame as normalTexture bends the
// base's, with its own scale; the base keeps its normal. Without it the
// coat is not normal-mapped even where the base is (the extension's rule):
// its normal is the surface's while the base's is bent. Materials without
// a coat or without any normal map have no coat normal of their own.
TEST(GltfNormalMaps, TheCoatHasItsOwnNormalMap) {
  TempDir dir("coat_normal");
  // 30 degrees towards +u (the quad's +x).
  write_bytes(dir.path / "n.png", png_1x1(q8(s30), q8(0), q8(c30)));
  auto hit_of = [&](const char* name, bool base_map, bool coat_map, float coat) {
    GltfQuad q = gltf_quad();
    q.doc["images"] = Json::array({{{"uri", "n.png"}}});
    q.doc["textures"] = Json::parse(R"([{"source": 0}])");
    q.doc["materials"][0]["name"] = name;
    if (base_map) q.doc["materials"][0]["normalTexture"] = {{"index", 0}};
    Json ext = {{"clearcoatFactor", coat}};
    if (coat_map) ext["clearcoatNormalTexture"] = {{"index", 0}, {"scale", 0.5}};
    q.doc["materials"][0]["extensions"] = {{"KHR_materials_clearcoat", ext}};
    q.doc["extensionsUsed"] = {"KHR_materials_clearcoat"};
    const std::string file = std::string(name) + ".gltf";
    write_gltf(dir.path / file, q);
    LogCapture log;
    SceneData d = load_scene_data(dir.path / file);
    EXPECT_TRUE(log.lines().empty()) << log.lines()[0];
    const Material& m = d.materials[d.tri_material[0]];
    EXPECT_EQ(m.clearcoat_normal_tex.present(), coat_map) << name;
    if (coat_map) {
      EXPECT_FLOAT_EQ(m.clearcoat_normal_scale, 0.5f);
    }
    Scene scene(std::move(d), std::make_unique<Environment>(Vec3(1.0f)));
    SurfaceHit hit;
    EXPECT_TRUE(scene.intersect(Ray{Vec3(0.3f, 1.0f, 0.6f), Vec3(0, -1, 0)}, &hit));
    return hit;
  };
  const float tol = kTexelTolerance;
  // Scale 0.5 halves x and y before normalising: atan(0.5 tan 30 deg).
  const float half_bend = std::atan(0.5f * std::tan(kPi / 6));
  const Vec3 bent(s30, c30, 0), half_bent(std::sin(half_bend), std::cos(half_bend), 0);
  SurfaceHit coat_only = hit_of("coat_only", false, true, 1.0f);
  expect_near3(coat_only.ns, Vec3(0, 1, 0), 0.0f);
  expect_near3(coat_only.coat_ns, half_bent, tol);
  SurfaceHit both = hit_of("both", true, true, 1.0f);
  expect_near3(both.ns, bent, tol);
  expect_near3(both.coat_ns, half_bent, tol);
  SurfaceHit base_only = hit_of("base_only", true, false, 1.0f);
  expect_near3(base_only.ns, bent, tol);
  expect_near3(base_only.coat_ns, Vec3(0, 1, 0), 0.0f);
  SurfaceHit no_coat = hit_of("no_coat", true, false, 0.0f);
  expect_near3(no_coat.ns, bent, tol);
  expect_near3(no_coat.coat_ns, Vec3(0.0f), 0.0f);
}

// KHR_materials_sheen: the factors as written, a value outside [0, 1]
// warned about (material and key) and the extension's default used; the
// colour texture (sRGB RGB) and the roughness texture (its alpha, linear),
// here one RGBA image as exporters pack them, multiply the factors.
TEST(GltfMaterials, SheenFactorsAndTexturesAreRead) {
  TempDir dir("sheen");
  {
    LogCapture log;
    struct Case {
      const char* name;
      Json ext;  // null: no extension
      Vec3 color;
      float roughness;
    } cases[] = {{"velvet",
                  {{"sheenColorFactor", {1.0, 0.5, 0.25}}, {"sheenRoughnessFactor", 0.3}},
                  Vec3(1.0f, 0.5f, 0.25f),
                  0.3f},
                 {"none", nullptr, Vec3(0.0f), 0.0f},
                 {"bright",
                  {{"sheenColorFactor", {2.0, 0.5, 0.25}}, {"sheenRoughnessFactor", 0.3}},
                  Vec3(0.0f),
                  0.3f},
                 {"rough_above",
                  {{"sheenColorFactor", {1.0, 1.0, 1.0}}, {"sheenRoughnessFactor", -1}},
                  Vec3(1.0f),
                  0.0f}};
    for (const Case& c : cases) {
      SCOPED_TRACE(c.name);
      const Material m = material_with_extension(dir.path, c.name, "KHR_materials_sheen", c.ext);
      EXPECT_FLOAT_EQ(m.sheen_color.x, c.color.x);
      EXPECT_FLOAT_EQ(m.sheen_color.y, c.color.y);
      EXPECT_FLOAT_EQ(m.sheen_color.z, c.color.z);
      EXPECT_FLOAT_EQ(m.sheen_roughness, c.roughness);
    }
    expect_warnings(log.lines(), {{"\"bright\"", "sheenColorFactor [2, 0.5, 0.25]"},
                                  {"\"rough_above\"", "sheenRoughnessFactor -1"}});
    expect_extension_read(log.lines());
  }
  const unsigned char px[] = {255, 128, 0, 255, 0, 0, 255, 51};
  write_bytes(dir.path / "fibre.png", encode_png(px, 2, 1, 4));
  GltfQuad q = gltf_quad();
  q.doc["materials"][0]["name"] = "cloth";
  q.doc["materials"][0]["extensions"] = {{"KHR_materials_sheen",
                                          {{"sheenColorFactor", {1.0, 0.5, 1.0}},
                                           {"sheenColorTexture", {{"index", 0}}},
                                           {"sheenRoughnessFactor", 0.8},
                                           {"sheenRoughnessTexture", {{"index", 0}}}}}};
  q.doc["extensionsUsed"] = {"KHR_materials_sheen"};
  q.doc["textures"] = Json::array({{{"source", 0}}});
  q.doc["images"] = Json::array({{{"uri", "fibre.png"}}});
  write_gltf(dir.path / "cloth.gltf", q);
  LogCapture log;
  SceneData d = load_scene_data(dir.path / "cloth.gltf");
  const Material& m = d.materials[d.tri_material[0]];
  ASSERT_GE(m.sheen_color_tex.index, 0);
  ASSERT_GE(m.sheen_rough_tex.index, 0);
  EXPECT_TRUE(m.has_textures());
  const auto [left, right] = quad_hits(d);
  const float half = srgb_to_linear(128.0f / 255.0f);
  EXPECT_NEAR(left.sheen_color.x, 1.0f, 1e-5f);
  EXPECT_NEAR(left.sheen_color.y, 0.5f * half, 1e-5f);
  EXPECT_NEAR(left.sheen_color.z, 0.0f, 1e-5f);
  EXPECT_NEAR(right.sheen_color.x, 0.0f, 1e-5f);
  EXPECT_NEAR(right.sheen_color.z, 1.0f, 1e-5f);
  EXPECT_NEAR(left.sheen_roughness, 0.8f, 1e-5f);
  EXPECT_NEAR(right.sheen_roughness, 0.8f * 0.2f, 1e-5f);  // alpha 51 / 255, linear
  expect_extension_read(log.lines());
}

// KHR_materials_clearcoat's factors as written (Blender 3.4 writes
// clearcoatFactor = Clearcoat and clearcoatRoughnessFactor = Clearcoat
// Roughness for a Principled BSDF whose Clearcoat is above 0); no
// extension is 0; a value outside [0, 1] is warned about, naming the
// material and the key, and 0 used. The extension is read, so it is not in
// the "ignores" warning.
TEST(GltfMaterials, ClearcoatFactorsAreRead) {
  TempDir dir("clearcoat");
  LogCapture log;
  struct Case {
    const char* name;
    Json ext;  // null: no extension
    float factor, roughness;
  } cases[] = {
      {"blender", {{"clearcoatFactor", 1.0}, {"clearcoatRoughnessFactor", 0.03}}, 1.0f, 0.03f},
      {"half", {{"clearcoatFactor", 0.5}}, 0.5f, 0.0f},
      {"none", nullptr, 0.0f, 0.0f},
      {"rough_above", {{"clearcoatFactor", 1.0}, {"clearcoatRoughnessFactor", 2.0}}, 1.0f, 0.0f}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Material m = material_with_extension(dir.path, c.name, "KHR_materials_clearcoat", c.ext);
    EXPECT_FLOAT_EQ(m.clearcoat, c.factor);
    EXPECT_FLOAT_EQ(m.clearcoat_roughness, c.roughness);
  }
  expect_warnings(log.lines(), {{"\"rough_above\"", "clearcoatRoughnessFactor 2"}});
  expect_extension_read(log.lines());
}

// KHR_materials_volume's attenuation as written: sigma_a = -ln(c) / d per
// channel; no extension, no distance (the extension's +inf) or white is
// clear; a distance not above 0 or a colour outside [0, 1] is warned about,
// naming the material and the key, and no absorption used. The extension
// is read, so it is not in the "ignores" warning.
TEST(GltfMaterials, VolumeAttenuationIsRead) {
  TempDir dir("volume");
  LogCapture log;
  struct Case {
    const char* name;
    Json ext;  // null: no extension
    Vec3 sigma;
  } cases[] = {
      {"tinted",
       {{"thicknessFactor", 0.1},
        {"attenuationDistance", 2.0},
        {"attenuationColor", {0.5, 0.25, 1.0}}},
       Vec3(std::log(2.0f) / 2, std::log(4.0f) / 2, 0.0f)},
      {"no_distance", {{"attenuationColor", {0.5, 0.5, 0.5}}}, Vec3(0.0f)},
      {"none", nullptr, Vec3(0.0f)},
      {"zero_distance", {{"attenuationDistance", 0.0}}, Vec3(0.0f)},
      {"bright", {{"attenuationDistance", 1.0}, {"attenuationColor", {1.5, 1, 1}}}, Vec3(0.0f)}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Material m = material_with_extension(dir.path, c.name, "KHR_materials_volume", c.ext);
    expect_near3(m.attenuation, c.sigma, 1e-6f);
  }
  expect_warnings(log.lines(), {{"\"zero_distance\"", "attenuationDistance 0"},
                                {"\"bright\"", "attenuationColor"}});
  expect_extension_read(log.lines());
}

}  // namespace
}  // namespace dofarm::render
