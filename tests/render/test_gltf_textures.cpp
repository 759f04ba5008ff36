// glTF texture slots beyond the base colour: KHR_materials_specular's,
// _transmission's and _clearcoat's textures scaling their factors, and
// texture coordinate sets (TEXCOORD_1, texCoord and KHR_texture_transform's
// override); the files are written by the tests.
#include "tests/render/gltf_fixture.h"

namespace dofarm::render {
namespace {

using namespace gltf_fixture;

// KHR_materials_specular's textures, which assimp 5.2 does not read and
// dofarm resolves from the file's JSON (textures -> images -> a file, or
// assimp's "*k" for the k-th image held in the file): specularTexture's A
// multiplies specularFactor (linear) and specularColorTexture's RGB (sRGB)
// specularColorFactor, each with its own transform. The images are the
// second and third of the file, in a .gltf beside it and in a .glb (where
// the first image, the base colour's, is embedded too, so the numbering of
// embedded images is what is checked), and under a NEAREST, CLAMP sampler.
TEST(GltfMaterials, SpecularTexturesScaleTheirFactors) {
  TempDir dir("specular_textures");
  const std::string base = test_png();
  // Texel 0: colour (255, 128, 0), alpha 51; texel 1: (0, 0, 255), alpha 255.
  const unsigned char px[] = {255, 128, 0, 51, 0, 0, 255, 255};
  const std::string spec = encode_png(px, 2, 1, 4);
  auto material = [](GltfQuad* q) {
    Json& m = q->doc["materials"][0];
    m["name"] = "spec";
    m["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 0}};
    // specularColorTexture mirrored in u: texel 1 at x = 0.25.
    Json mirrored = {{"offset", {1, 0}}, {"scale", {-1, 1}}};
    Json color_tex = {{"index", 2}};
    color_tex["extensions"]["KHR_texture_transform"] = mirrored;
    Json ext = {{"specularFactor", 0.8}, {"specularColorFactor", {1.0, 0.5, 2.0}}};
    ext["specularTexture"] = {{"index", 1}};
    ext["specularColorTexture"] = color_tex;
    m["extensions"]["KHR_materials_specular"] = ext;
    q->doc["extensionsUsed"] = {"KHR_materials_specular", "KHR_texture_transform"};
    q->doc["samplers"] = Json::array({{{"magFilter", 9728}, {"wrapS", 33071}}});
    q->doc["textures"] =
        Json::array({{{"source", 0}}, {{"source", 1}}, {{"source", 2}, {"sampler", 0}}});
  };
  GltfQuad beside = gltf_quad();
  material(&beside);
  write_bytes(dir.path / "base.png", base);
  write_bytes(dir.path / "spec.png", spec);
  write_bytes(dir.path / "tint.png", spec);
  beside.doc["images"] =
      Json::array({{{"uri", "base.png"}}, {{"uri", "spec.png"}}, {{"uri", "tint.png"}}});
  write_gltf(dir.path / "beside.gltf", beside);
  GltfQuad glb = gltf_quad();
  material(&glb);
  Json images = Json::array();
  for (const std::string* png : {&base, &spec, &spec}) {
    glb.doc["bufferViews"].push_back(
        {{"buffer", 0}, {"byteOffset", glb.bin.size()}, {"byteLength", png->size()}});
    glb.bin += *png;
    images.push_back(
        {{"bufferView", glb.doc["bufferViews"].size() - 1}, {"mimeType", "image/png"}});
  }
  glb.doc["images"] = images;
  write_glb(dir.path / "spec.glb", glb);
  GltfQuad data_uri = gltf_quad();
  material(&data_uri);
  const std::string spec_uri = "data:image/png;base64," + base64(spec);
  data_uri.doc["images"] =
      Json::array({{{"uri", "base.png"}}, {{"uri", spec_uri}}, {{"uri", spec_uri}}});
  write_gltf(dir.path / "data_uri.gltf", data_uri);
  const float orange_g = srgb_to_linear(128.0f / 255.0f);
  for (const char* file : {"beside.gltf", "spec.glb", "data_uri.gltf"}) {
    SCOPED_TRACE(file);
    LogCapture log;
    SceneData d = load_scene_data(dir.path / file);
    EXPECT_TRUE(log.lines().empty()) << log.lines()[0];
    const Material& m = d.materials[d.tri_material[0]];
    ASSERT_GE(m.specular_tex.index, 0);
    ASSERT_GE(m.specular_color_tex.index, 0);
    EXPECT_NE(m.specular_tex.index, m.base_color_tex.index);
    EXPECT_TRUE(d.textures[size_t(m.specular_color_tex.index)].sampler.nearest);
    EXPECT_EQ(d.textures[size_t(m.specular_color_tex.index)].sampler.wrap_u, TextureWrap::kClamp);
    const auto [left, right] = quad_hits(d);         // u = 0.25 and 0.75
    EXPECT_NEAR(left.specular, 0.8f * 0.2f, 1e-6f);  // alpha 51 / 255, linear
    EXPECT_NEAR(right.specular, 0.8f, 1e-6f);
    expect_near3(left.specular_color, Vec3(0.0f, 0.0f, 2.0f), 1e-6f);  // mirrored: texel 1
    expect_near3(right.specular_color, Vec3(1.0f, 0.5f * orange_g, 0.0f), 1e-6f);
  }
  // A buffer view that reaches beyond its buffer is refused, naming the image.
  glb.doc["bufferViews"][glb.doc["bufferViews"].size() - 1]["byteLength"] = 1u << 20;
  write_glb(dir.path / "cut.glb", glb);
  try {
    load_scene_data(dir.path / "cut.glb");
    ADD_FAILURE() << "cut.glb loaded";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("image 2: its buffer view lies outside its buffer"),
              std::string::npos)
        << e.what();
  }
}

// The extensions' textures as Blender 3.4 exports them (a Principled BSDF
// whose Transmission, Clearcoat or Clearcoat Roughness is fed by an image):
// transmissionTexture's R multiplies transmissionFactor, clearcoatTexture's
// R clearcoatFactor and clearcoatRoughnessTexture's G
// clearcoatRoughnessFactor, read linearly, with their own
// KHR_texture_transform. A 2 x 1 image: texel 0 (R 0, G 255), texel 1
// (R 255, G 51); looked up at the texel centres u = 0.25 and 0.75 through
// Scene::intersect.
TEST(GltfMaterials, TransmissionAndClearcoatTexturesScaleTheirFactors) {
  TempDir dir("extension_textures");
  const unsigned char px[] = {0, 255, 0, 255, 51, 0};
  write_bytes(dir.path / "mask.png", encode_png(px, 2, 1, 3));
  GltfQuad q = gltf_quad();
  q.doc["materials"][0]["name"] = "painted";
  // The clearcoat texture mirrors u (scale -1, offset 1): texel 1 at u = 0.25.
  const Json mirrored = {
      {"index", 0},
      {"extensions", {{"KHR_texture_transform", {{"offset", {1, 0}}, {"scale", {-1, 1}}}}}}};
  q.doc["materials"][0]["extensions"] = {
      {"KHR_materials_transmission",
       {{"transmissionFactor", 0.75}, {"transmissionTexture", {{"index", 0}}}}},
      {"KHR_materials_clearcoat",
       {{"clearcoatFactor", 0.5},
        {"clearcoatTexture", mirrored},
        {"clearcoatRoughnessFactor", 0.6},
        {"clearcoatRoughnessTexture", {{"index", 0}}}}}};
  q.doc["extensionsUsed"] = {"KHR_materials_transmission", "KHR_materials_clearcoat",
                             "KHR_texture_transform"};
  q.doc["textures"] = Json::array({{{"source", 0}}});
  q.doc["images"] = Json::array({{{"uri", "mask.png"}}});
  write_gltf(dir.path / "painted.gltf", q);
  LogCapture log;
  SceneData d = load_scene_data(dir.path / "painted.gltf");
  const Material& m = d.materials[d.tri_material[0]];
  EXPECT_FLOAT_EQ(m.transmission, 0.75f);
  EXPECT_FLOAT_EQ(m.clearcoat, 0.5f);
  EXPECT_FLOAT_EQ(m.clearcoat_roughness, 0.6f);
  ASSERT_GE(m.transmission_tex.index, 0);
  ASSERT_GE(m.clearcoat_tex.index, 0);
  ASSERT_GE(m.clearcoat_rough_tex.index, 0);
  EXPECT_TRUE(m.has_textures());
  const auto [left, right] = quad_hits(d);
  EXPECT_NEAR(left.transmission, 0.0f, 1e-6f);
  EXPECT_NEAR(right.transmission, 0.75f, 1e-6f);
  EXPECT_NEAR(left.clearcoat, 0.5f, 1e-6f);  // mirrored: texel 1
  EXPECT_NEAR(right.clearcoat, 0.0f, 1e-6f);
  EXPECT_NEAR(left.clearcoat_roughness, 0.6f, 1e-6f);
  EXPECT_NEAR(right.clearcoat_roughness, 0.6f * 0.2f, 1e-6f);  // 51 / 255, linear
  EXPECT_TRUE(log.lines().empty()) << log.lines()[0];
}

// glTF textureInfo.texCoord (or KHR_texture_transform's override) picks the
// set a texture reads: here TEXCOORD_1 runs against TEXCOORD_0 (u1 = 1 -
// u0), so a texture that reads it is mirrored. The base colour and the
// metallic-roughness texture (by the transform's override) read set 1, the
// emissive texture set 0, all from one 2 x 1 image. A normal map that reads
// set 1 is oriented by it: the tangent follows +u of that set (glTF
// 3.7.2.1). A mesh without TEXCOORD_1 whose material reads it is named in a
// warning and reads TEXCOORD_0; a scene where no texture reads set 1 does
// not load it.
TEST(GltfMaterials, TexturesReadTheSetTheyName) {
  TempDir dir("texcoord1");
  const unsigned char px[] = {255, 128, 0, 0, 0, 255};
  write_bytes(dir.path / "two.png", encode_png(px, 2, 1, 3));
  auto quad = [](bool with_set1) {
    GltfQuad q = gltf_quad();
    // Vertices (0,0,0), (0,0,1), (1,0,1), (1,0,0); TEXCOORD_0 has u = x, v = z.
    if (with_set1) add_vertex_attribute(&q, "TEXCOORD_1", {1, 0, 1, 1, 0, 1, 0, 0});
    q.doc["textures"] = Json::array({{{"source", 0}}});
    q.doc["images"] = Json::array({{{"uri", "two.png"}}});
    Json& m = q.doc["materials"][0];
    m["name"] = "two_sets";
    m["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 0}, {"texCoord", 1}};
    m["pbrMetallicRoughness"]["roughnessFactor"] = 1.0;
    m["pbrMetallicRoughness"]["metallicRoughnessTexture"] = {
        {"index", 0}, {"extensions", {{"KHR_texture_transform", {{"texCoord", 1}}}}}};
    m["emissiveTexture"] = {{"index", 0}};
    m["emissiveFactor"] = {1.0, 1.0, 1.0};
    m["normalTexture"] = {{"index", 0}, {"texCoord", 1}};
    q.doc["extensionsUsed"] = {"KHR_texture_transform"};
    return q;
  };
  const float half = srgb_to_linear(128.0f / 255.0f);
  write_gltf(dir.path / "two_sets.gltf", quad(true));
  {
    LogCapture log;
    SceneData d = load_scene_data(dir.path / "two_sets.gltf");
    EXPECT_TRUE(log.lines().empty()) << log.lines()[0];
    ASSERT_EQ(d.uvs1.size(), d.positions.size());
    const Material& m = d.materials[d.tri_material[0]];
    EXPECT_EQ(m.base_color_tex.uv.set, 1);
    EXPECT_EQ(m.metal_rough_tex.uv.set, 1);
    EXPECT_EQ(m.emission_tex.uv.set, 0);
    // TANGENT from set 1: u1 = 1 - x, so +u1 is -x (set 0's +u is +x).
    ASSERT_EQ(d.tangents.size(), d.positions.size());
    for (const SceneData::Tangent& t : d.tangents) expect_near3(t.t, Vec3(-1, 0, 0), 1e-5f);
    d.materials[0].normal_tex.index = -1;     // the hits below read the colours alone
    const auto [left, right] = quad_hits(d);  // x = 0.25 and 0.75
    expect_near3(left.base_color, Vec3(0.0f, 0.0f, 1.0f), 1e-5f);  // texel 1 through set 1
    expect_near3(right.base_color, Vec3(1.0f, half, 0.0f), 1e-5f);
    expect_near3(left.emission, Vec3(1.0f, half, 0.0f), 1e-5f);  // texel 0 through set 0
    expect_near3(right.emission, Vec3(0.0f, 0.0f, 1.0f), 1e-5f);
    EXPECT_NEAR(left.roughness, 0.0f, 1e-5f);              // G of texel 1 through set 1
    EXPECT_NEAR(right.roughness, 128.0f / 255.0f, 1e-5f);  // linear
  }
  write_gltf(dir.path / "one_set.gltf", quad(false));
  {
    LogCapture log;
    SceneData d = load_scene_data(dir.path / "one_set.gltf");
    expect_warnings(log.lines(), {{"has no TEXCOORD_1", "\"two_sets\" reads; TEXCOORD_0 used"}});
    const auto [left, right] = quad_hits(d);
    expect_near3(left.base_color, Vec3(1.0f, half, 0.0f), 1e-5f);
    for (const SceneData::Tangent& t : d.tangents) expect_near3(t.t, Vec3(1, 0, 0), 1e-5f);
  }
  GltfQuad set0 = quad(true);
  set0.doc["materials"][0]["pbrMetallicRoughness"].erase("baseColorTexture");
  set0.doc["materials"][0]["pbrMetallicRoughness"].erase("metallicRoughnessTexture");
  set0.doc["materials"][0].erase("normalTexture");
  write_gltf(dir.path / "set0.gltf", set0);
  EXPECT_TRUE(load_scene_data(dir.path / "set0.gltf").uvs1.empty());
}

// A texture that reads a texture coordinate set above TEXCOORD_1
// (texCoord, or KHR_texture_transform's override) is named in a warning per
// slot, with its material; TEXCOORD_0 is used.
TEST(GltfMaterials, TexturesReadingAnotherUvSetAreNamed) {
  TempDir dir("texcoord");
  const unsigned char px[] = {255, 128, 0, 255, 0, 0, 255, 51};
  write_bytes(dir.path / "two.png", encode_png(px, 2, 1, 4));
  GltfQuad q = gltf_quad();
  q.doc["materials"][0]["name"] = "second_set";
  q.doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 0},
                                                                       {"texCoord", 3}};
  q.doc["materials"][0]["extensions"] = {
      {"KHR_materials_sheen",
       {{"sheenColorFactor", {1.0, 1.0, 1.0}},
        {"sheenColorTexture",
         {{"index", 0}, {"extensions", {{"KHR_texture_transform", {{"texCoord", 2}}}}}}}}}};
  q.doc["extensionsUsed"] = {"KHR_materials_sheen", "KHR_texture_transform"};
  q.doc["textures"] = Json::array({{{"source", 0}}});
  q.doc["images"] = Json::array({{{"uri", "two.png"}}});
  write_gltf(dir.path / "second_set.gltf", q);
  LogCapture log;
  SceneData d = load_scene_data(dir.path / "second_set.gltf");
  EXPECT_GE(d.materials[d.tri_material[0]].sheen_color_tex.index, 0);
  expect_warnings(log.lines(), {{"\"second_set\"", "baseColorTexture reads TEXCOORD_3"},
                                {"\"second_set\"", "sheenColorTexture reads TEXCOORD_2"}});
}

}  // namespace
}  // namespace dofarm::render
