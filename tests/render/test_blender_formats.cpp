// Blender's Collada and FBX exports against its glTF export of the same
// scene (tests/data/blender/make_*.py). Orthographic cameras, which assimp
// 5.2 reads as perspective ones (worker/render/foreign_cameras.h): the scans
// on bytes with known answers; the Collada camera is the glTF one, the FBX
// one is refused by name, the perspective ones are the glTF one. FBX
// units, and the materials' metallic, which Blender writes as their
// reflectivity.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>

#include "common/error.h"
#include "common/file_bytes.h"
#include "common/jobspec.h"
#include "tests/render/render_fixtures.h"
#include "worker/render/camera.h"
#include "worker/render/foreign_cameras.h"
#include "worker/render/render_job.h"
#include "worker/render/scene_data.h"
#include "worker/render/scene_motion.h"

namespace dofarm::render {
namespace {

const std::filesystem::path kBlender = std::filesystem::path(DOFARM_TEST_DATA) / "blender";

// The 16:9 frame of the fixtures' camera, from the scene.
JobSpec scene_camera_spec() {
  JobSpec spec;
  spec.width = 96;
  spec.height = 54;
  spec.camera_from_scene = true;
  return spec;
}

// The same place (within `tol`) and the same rotation, whichever sign each
// file's quaternion has.
void expect_same_pose(const CameraState& a, const CameraState& b, float tol) {
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(b.position[i], a.position[i], tol) << i;
  float dot = 0;
  for (int i = 0; i < 4; ++i) dot += a.rotation[i] * b.rotation[i];
  EXPECT_NEAR(std::fabs(dot), 1.0f, 1e-5f);
}

// A small frame of a fixture from its own camera under a white sky.
FrameBuffers render_fixture(const char* file, float aperture, const std::string& camera = "") {
  JobSpec job = testing::make_spec(48, 27, Vec3(0), Vec3(0, 0, -1), 40, 11.0f, aperture);
  job.camera_from_scene = true;
  job.versions = 1;
  job.reference_spp = 4;
  return render_frame(
      *testing::make_scene(load_scene_data(kBlender / file, camera), testing::constant_env(1.0f)),
      job, 0);
}

// The same view depth and CoC in every pixel, where the plane covers part
// of the view (not all of it and not none).
void expect_same_depths(const FrameBuffers& a, const FrameBuffers& b) {
  ASSERT_EQ(a.depth.size(), b.depth.size());
  int plane = 0;
  for (size_t i = 0; i < a.depth.size(); ++i) {
    if (a.depth[i] > 0) ++plane;
    ASSERT_NEAR(b.depth[i], a.depth[i], 1e-3f * std::max(1.0f, a.depth[i])) << "pixel " << i;
    ASSERT_NEAR(b.coc[i], a.coc[i], 1e-3f) << "pixel " << i;
  }
  EXPECT_GT(plane, int(a.depth.size()) / 10);
  EXPECT_LT(plane, int(a.depth.size()));
}

std::string collada_with(const std::string& optics) {
  return R"(<?xml version="1.0"?><COLLADA><library_cameras>
    <camera id="Top-camera" name="Top"><optics><technique_common>)" +
         optics + R"(</technique_common></optics></camera>
    <camera id="Side-camera" name="Side"><optics><technique_common>
      <perspective><xfov sid="xfov">40</xfov><aspect_ratio>1.5</aspect_ratio>
      <znear>0.1</znear><zfar>100</zfar></perspective></technique_common></optics></camera>
    </library_cameras><library_visual_scenes><visual_scene id="Scene">
    <node id="TopNode" name="Plan view" type="NODE"><instance_camera url="#Top-camera"/>
      <node id="Child" name="Child" type="NODE"/></node>
    <node id="SideNode" name="Elevation" type="NODE"><instance_camera url="#Side-camera"/></node>
    </visual_scene></library_visual_scenes></COLLADA>)";
}

TEST(ForeignCameras, ColladaOrthographicSizeFromAnyTwoOfXmagYmagAndAspect) {
  struct Case {
    const char* optics;
    double xmag, ymag;
  } cases[] = {
      {"<orthographic><xmag sid=\"xmag\">3</xmag><aspect_ratio>1.5</aspect_ratio></orthographic>",
       3, 2},
      {"<orthographic><ymag>2</ymag><aspect_ratio>1.5</aspect_ratio></orthographic>", 3, 2},
      {"<orthographic><xmag>4</xmag><ymag> 1 </ymag></orthographic>", 4, 1},
      {"<orthographic><xmag>4</xmag></orthographic>", 4, 0},  // no height: refused later
      {"<orthographic><xmag>-4</xmag><ymag>1</ymag></orthographic>", 0, 1},
  };
  for (const Case& c : cases) {
    const ForeignCameras f = scan_collada_cameras(collada_with(c.optics));
    ASSERT_EQ(f.cameras.size(), 2u) << c.optics;
    EXPECT_TRUE(f.any_orthographic());
    // assimp names a Collada camera after the node that holds it.
    const ForeignCamera* top = f.find("Plan view");
    ASSERT_NE(top, nullptr);
    EXPECT_EQ(top->id, "Top-camera");
    EXPECT_TRUE(top->orthographic);
    EXPECT_DOUBLE_EQ(top->xmag, c.xmag) << c.optics;
    EXPECT_DOUBLE_EQ(top->ymag, c.ymag) << c.optics;
    const ForeignCamera* side = f.find("Elevation");
    ASSERT_NE(side, nullptr);
    EXPECT_EQ(side->id, "Side-camera");
    EXPECT_FALSE(side->orthographic);
    EXPECT_EQ(f.find("Child"), nullptr);  // holds no camera; two cameras: no guess
  }
  const ForeignCameras none = scan_collada_cameras("<COLLADA><library_geometries/></COLLADA>");
  EXPECT_TRUE(none.cameras.empty());
  EXPECT_FALSE(none.any_orthographic());
}

std::string fbx_string(const std::string& s) {
  std::string out = "S";
  const uint32_t n = uint32_t(s.size());
  out.append(reinterpret_cast<const char*>(&n), 4);  // little-endian, as FBX
  return out + s;
}

std::string fbx_projection(int32_t value) {
  std::string p = fbx_string("CameraProjectionType") + fbx_string("enum") + fbx_string("") +
                  fbx_string("") + "I";
  p.append(reinterpret_cast<const char*>(&value), 4);
  return p;
}

TEST(ForeignCameras, FbxProjectionTypeIsReadFromBinaryAndAsciiFiles) {
  const std::string magic("Kaydara FBX Binary  \0\x1a\0", 23);
  // The Definitions' template (0), a perspective camera's own 0, and a
  // property of another name holding 1.
  const std::string persp = magic + "..." + fbx_projection(0) + "..P" + fbx_projection(0) +
                            fbx_string("OrthoZoom") + fbx_string("CameraProjection") +
                            fbx_string("enum") + fbx_string("") + fbx_string("") + "I" +
                            std::string("\x01\0\0\0", 4);
  EXPECT_FALSE(scan_fbx_cameras(persp).any_orthographic());
  const ForeignCameras two = scan_fbx_cameras(persp + fbx_projection(1) + fbx_projection(1));
  EXPECT_EQ(two.cameras.size(), 2u);
  EXPECT_EQ(two.fbx_ortho_zoom, 0.0);  // no OrthoZoom in the file
  // OrthoZoom: the template's 1, then the camera's own 6 (a double).
  auto zoom = [](double v) {
    std::string p = fbx_string("OrthoZoom") + fbx_string("double") + fbx_string("Number") +
                    fbx_string("") + "D";
    p.append(reinterpret_cast<const char*>(&v), 8);
    return p;
  };
  const std::string zoomed = magic + zoom(1.0) + fbx_projection(1) + zoom(6.0);
  EXPECT_EQ(fbx_property_values(zoomed, "OrthoZoom"), (std::vector<double>{1.0, 6.0}));
  EXPECT_EQ(scan_fbx_cameras(zoomed).fbx_ortho_zoom, 6.0);
  // A longer name that ends in the same letters is another property.
  EXPECT_TRUE(fbx_property_values(magic + fbx_string("XOrthoZoom") + fbx_string("double") +
                                      fbx_string("") + fbx_string("") + "D" + std::string(8, '\0'),
                                  "OrthoZoom")
                  .empty());
  EXPECT_TRUE(two.any_orthographic());
  EXPECT_EQ(two.find(""), nullptr);  // FBX cameras are not named by the scan
  // Cut short after the name: nothing read, nothing out of bounds.
  const std::string cut = magic + fbx_projection(1);
  EXPECT_FALSE(scan_fbx_cameras(cut.substr(0, cut.size() - 3)).any_orthographic());

  const std::string ascii =
      "; FBX 7.4.0 project file\nObjects:  {\n P: \"CameraProjectionType\", \"enum\", \"\", "
      "\"\",0\n";
  EXPECT_FALSE(scan_fbx_cameras(ascii).any_orthographic());
  EXPECT_TRUE(scan_fbx_cameras(ascii + "P: \"CameraProjectionType\", \"enum\", \"\", \"\",1\n}\n")
                  .any_orthographic());
  EXPECT_EQ(scan_fbx_cameras(ascii + "P: \"OrthoZoom\", \"double\", \"Number\", \"\",6.5\n")
                .fbx_ortho_zoom,
            6.5);
}

// The start-up scene's camera made Orthographic (scale 6, 16:9, Clip Start
// 0.5), exported by Blender as glTF, Collada and FBX: the same camera. FBX
// holds the scale as OrthoZoom and Clip Start in centimetres.
TEST(ForeignCameras, BlendersColladaAndFbxOrthographicCamerasAreItsGltfCamera) {
  const SceneData gltf = load_scene_data(kBlender / "ortho_camera.glb");
  ASSERT_TRUE(gltf.camera_refused.empty()) << gltf.camera_refused;
  ASSERT_TRUE(gltf.scene_camera);
  EXPECT_NEAR(gltf.scene_camera->ymag, 3.0f / (16.0f / 9.0f), 1e-5f);
  const CameraState a = camera_for_frame(scene_camera_spec(), gltf, 0);
  EXPECT_NEAR(a.ortho_height, 2.0f * 3.0f / (16.0f / 9.0f), 1e-5f);
  for (const char* file : {"ortho_camera.dae", "ortho_camera.fbx"}) {
    SCOPED_TRACE(file);
    const SceneData other = load_scene_data(kBlender / file);
    ASSERT_TRUE(other.camera_refused.empty()) << other.camera_refused;
    ASSERT_TRUE(other.scene_camera);
    EXPECT_NEAR(other.scene_camera->ymag, gltf.scene_camera->ymag, 1e-5f);
    EXPECT_NEAR(other.scene_camera->aspect, gltf.scene_camera->aspect, 1e-5f);
    EXPECT_EQ(other.scene_camera->yfov_deg, 0.0f);
    EXPECT_NEAR(other.scene_camera->znear, 0.5f, 1e-6f);
    EXPECT_NEAR(other.scene_camera->zfar, gltf.scene_camera->zfar, 1e-3f);
    const CameraState b = camera_for_frame(scene_camera_spec(), other, 0);
    EXPECT_NEAR(b.ortho_height, a.ortho_height, 1e-5f);
    EXPECT_EQ(b.fov_deg, 0.0f);
    expect_same_pose(a, b, 1e-3f);

    // Rendered: the plane fills the same pixels at the same view depths (the
    // materials differ), through a pinhole and through the lens on Clip
    // Start.
    for (const float aperture : {0.0f, 0.3f}) {
      SCOPED_TRACE(aperture);
      expect_same_depths(render_fixture("ortho_camera.glb", aperture),
                         render_fixture(file, aperture));
    }
  }
}

// The same FBX file, its creator renamed: another exporter's OrthoZoom has
// no agreed unit, so its orthographic camera is refused by name; the
// perspective FBX is not refused.
TEST(ForeignCameras, AnFbxOrthographicCameraNotFromBlenderIsRefused) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("dofarm_fbx_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::string bytes;
  {
    std::ifstream in(kBlender / "ortho_camera.fbx", std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  for (size_t p = bytes.find("Blender"); p != std::string::npos; p = bytes.find("Blender", p))
    bytes.replace(p, 7, "Modeler");
  std::ofstream(dir / "other.fbx", std::ios::binary) << bytes;
  const SceneData ortho = load_scene_data(dir / "other.fbx");
  std::filesystem::remove_all(dir);
  EXPECT_NE(ortho.camera_refused.find("\"Camera\" is orthographic (FBX CameraProjectionType 1) "
                                      "with OrthoZoom 6"),
            std::string::npos)
      << ortho.camera_refused;
  EXPECT_NE(ortho.camera_refused.find("export the scene as glTF"), std::string::npos);
  JobSpec spec;
  spec.width = spec.height = 8;
  spec.camera_from_scene = true;
  spec.key_locations["camera.from_scene"] = FileLoc{"job.toml", 4, 1};
  try {
    camera_for_frame(spec, ortho, 0);
    FAIL() << "rendered an FBX orthographic camera as a perspective one";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "camera.from_scene");
    EXPECT_NE(std::string(e.what()).find("orthographic"), std::string::npos) << e.what();
  }
  const SceneData persp = load_scene_data(kBlender / "persp_camera.fbx");
  EXPECT_TRUE(persp.camera_refused.empty()) << persp.camera_refused;
  ASSERT_TRUE(persp.scene_camera);
  EXPECT_GT(persp.scene_camera->yfov_deg, 0.0f);
}

// A Blender scene with a perspective and an orthographic camera
// (make_two_cameras.py): the binary FBX file's records name each camera by
// its Model, so either renders as its glTF twin when the job names it; the
// orthographic one from its own OrthoZoom. The same file from another
// exporter still has its perspective camera and refuses the orthographic
// one by name. A truncated file parses to nothing, out of bounds nowhere.
// two_cameras.fbx's cameras as a scan of it finds them, binary or ASCII:
// "Camera" perspective, "Top" orthographic with Orthographic Scale 5.
void expect_two_cameras(const ForeignCameras& scan) {
  ASSERT_EQ(scan.cameras.size(), 2u);
  const ForeignCamera* persp = scan.find("Camera");
  const ForeignCamera* ortho = scan.find("Top");
  ASSERT_TRUE(persp && ortho);
  EXPECT_FALSE(persp->orthographic);
  EXPECT_TRUE(ortho->orthographic);
  EXPECT_DOUBLE_EQ(ortho->ortho_zoom, 5.0);
}

// The bytes of two_cameras.fbx (binary or ASCII) as another exporter's,
// its creator renamed: "Top" is refused by name (its OrthoZoom has no
// agreed unit), "Camera" loads.
void expect_other_exporters_two_cameras(std::string bytes) {
  for (size_t p = bytes.find("Blender"); p != std::string::npos; p = bytes.find("Blender", p))
    bytes.replace(p, 7, "Modeler");
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("dofarm_fbx2_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "other.fbx", std::ios::binary) << bytes;
  const SceneData top_cam = load_scene_data(dir / "other.fbx", "Top");
  const SceneData main_cam = load_scene_data(dir / "other.fbx", "Camera");
  std::filesystem::remove_all(dir);
  EXPECT_NE(top_cam.camera_refused.find("\"Top\" is orthographic (FBX CameraProjectionType 1) "
                                        "with OrthoZoom 5"),
            std::string::npos)
      << top_cam.camera_refused;
  EXPECT_TRUE(main_cam.camera_refused.empty()) << main_cam.camera_refused;
}

TEST(ForeignCameras, EachCameraOfABlenderFbxFileIsFoundByName) {
  const std::string bytes = read_file_bytes(kBlender / "two_cameras.fbx");
  const std::vector<FbxNode> top = parse_fbx_binary(bytes);
  std::set<std::string> names;
  for (const FbxNode& n : top) names.insert(n.name);
  for (const char* want : {"FBXHeaderExtension", "Definitions", "Objects", "Connections"})
    EXPECT_TRUE(names.count(want)) << want;
  expect_two_cameras(scan_fbx_cameras(bytes));
  for (size_t cut : {size_t(30), bytes.size() / 3, 2 * bytes.size() / 3})
    EXPECT_TRUE(parse_fbx_binary(bytes.substr(0, cut)).empty()) << cut;

  for (const char* name : {"Camera", "Top"}) {
    SCOPED_TRACE(name);
    const SceneData gltf = load_scene_data(kBlender / "two_cameras.glb", name);
    const SceneData fbx = load_scene_data(kBlender / "two_cameras.fbx", name);
    ASSERT_TRUE(fbx.camera_refused.empty()) << fbx.camera_refused;
    ASSERT_TRUE(gltf.scene_camera && fbx.scene_camera);
    EXPECT_NEAR(fbx.scene_camera->ymag, gltf.scene_camera->ymag, 1e-5f);
    EXPECT_NEAR(fbx.scene_camera->yfov_deg, gltf.scene_camera->yfov_deg, 1e-3f);
    // Clip Start (the orthographic lens's plane; other formats' perspective
    // cameras are not clipped).
    if (gltf.scene_camera->ymag > 0) {
      EXPECT_NEAR(fbx.scene_camera->znear, gltf.scene_camera->znear, 1e-5f);
    }
    const CameraState a = camera_for_frame(scene_camera_spec(), gltf, 0);
    const CameraState b = camera_for_frame(scene_camera_spec(), fbx, 0);
    EXPECT_NEAR(b.ortho_height, a.ortho_height, 1e-5f);
    expect_same_pose(a, b, 1e-3f);
    expect_same_depths(render_fixture("two_cameras.glb", 0.3f, name),
                       render_fixture("two_cameras.fbx", 0.3f, name));
  }
  EXPECT_GT(load_scene_data(kBlender / "two_cameras.fbx", "Top").scene_camera->ymag, 0.0f);
  EXPECT_EQ(load_scene_data(kBlender / "two_cameras.fbx", "Camera").scene_camera->ymag, 0.0f);
  expect_other_exporters_two_cameras(bytes);
}

// The records of two parsed FBX files agree: the same names and nesting,
// numbers equal, strings equal once a binary "Name\0\1Class" is written as
// ASCII "Class::Name". Flags and raw bytes are written differently; only
// their places are compared.
void expect_same_records(const std::vector<FbxNode>& binary, const std::vector<FbxNode>& ascii,
                         const std::string& path) {
  ASSERT_EQ(binary.size(), ascii.size()) << path;
  for (size_t i = 0; i < binary.size(); ++i) {
    const FbxNode& b = binary[i];
    const FbxNode& a = ascii[i];
    const std::string at = path + "/" + b.name;
    ASSERT_EQ(b.name, a.name) << at;
    ASSERT_EQ(b.properties.size(), a.properties.size()) << at;
    for (size_t k = 0; k < b.properties.size(); ++k) {
      const FbxNode::Property& pb = b.properties[k];
      const FbxNode::Property& pa = a.properties[k];
      if (pb.type == 'S') {
        std::string want = pb.s;
        const size_t sep = want.find(std::string("\0\1", 2));
        if (sep != std::string::npos) want = want.substr(sep + 2) + "::" + want.substr(0, sep);
        EXPECT_EQ(pa.s, want) << at << " property " << k;
      } else if (pb.type != 'C' && pb.type != 'R') {
        EXPECT_EQ(pa.d, pb.d) << at << " property " << k;
        EXPECT_EQ(pa.type, pb.type == 'F' || pb.type == 'D' ? 'D' : 'L') << at << " property " << k;
      }
    }
    expect_same_records(b.children, a.children, at);
  }
}

// two_cameras.fbx as FBX ASCII (tests/data/blender/fbx_to_ascii.py wrote
// it; Blender writes only binary FBX, other exporters ASCII too): its
// records parse to the binary file's, so each camera is found by its name
// and renders as it does from the binary file, the perspective one as its
// glTF twin; from another exporter the orthographic one is refused by name
// and the perspective one still renders (before, an ASCII file's cameras
// could not be told apart, and both were refused). Broken text parses to
// nothing.
TEST(ForeignCameras, EachCameraOfAnAsciiFbxFileIsFoundByName) {
  const std::string text = read_file_bytes(kBlender / "two_cameras_ascii.fbx");
  const std::vector<FbxNode> ascii = parse_fbx_ascii(text);
  ASSERT_FALSE(ascii.empty());
  expect_same_records(parse_fbx_binary(read_file_bytes(kBlender / "two_cameras.fbx")), ascii, "");
  EXPECT_TRUE(parse_fbx_binary(text).empty());
  expect_two_cameras(scan_fbx_cameras(text));
  for (const char* name : {"Camera", "Top"}) {
    SCOPED_TRACE(name);
    const SceneData binary = load_scene_data(kBlender / "two_cameras.fbx", name);
    const SceneData from_ascii = load_scene_data(kBlender / "two_cameras_ascii.fbx", name);
    ASSERT_TRUE(from_ascii.camera_refused.empty()) << from_ascii.camera_refused;
    ASSERT_TRUE(binary.scene_camera && from_ascii.scene_camera);
    EXPECT_EQ(from_ascii.scene_camera->ymag, binary.scene_camera->ymag);
    EXPECT_EQ(from_ascii.scene_camera->yfov_deg, binary.scene_camera->yfov_deg);
    EXPECT_EQ(from_ascii.positions.size(), binary.positions.size());
    expect_same_pose(camera_for_frame(scene_camera_spec(), binary, 0),
                     camera_for_frame(scene_camera_spec(), from_ascii, 0), 1e-5f);
  }
  expect_same_depths(render_fixture("two_cameras.glb", 0.3f, "Camera"),
                     render_fixture("two_cameras_ascii.fbx", 0.3f, "Camera"));
  expect_other_exporters_two_cameras(text);

  for (size_t cut : {text.size() / 3, 2 * text.size() / 3, text.size() - 3})
    EXPECT_TRUE(parse_fbx_ascii(text.substr(0, cut)).empty()) << cut;
  EXPECT_TRUE(parse_fbx_ascii(std::string(100000, '{')).empty());
  std::string deep;  // nested deeper than any file: refused, not recursed into
  for (int i = 0; i < 100; ++i) deep += "A: {\n";
  EXPECT_TRUE(parse_fbx_ascii(deep + std::string(100, '}')).empty());
  EXPECT_EQ(parse_fbx_ascii("A: {\nA: {\n}\n}\n").size(), 1u);
  EXPECT_TRUE(parse_fbx_ascii("A: 1 }\n").empty());
  EXPECT_TRUE(parse_fbx_ascii("A: \"open\n").empty());
  EXPECT_TRUE(parse_fbx_ascii("; only a comment\n").empty());
  // Lists go on after a comma at a line's end; comments and flags; an
  // empty first value; an array is skipped.
  const std::vector<FbxNode> small = parse_fbx_ascii(
      "; c\nN: 1, -2.5e-1, \"a&quot;b\", T ; note\nM: 7400,\n 8 {\n  a: *3 {\n   a: 1,2,3\n  }\n"
      "  C: ,\"x\"\n }\n");
  ASSERT_EQ(small.size(), 2u);
  ASSERT_EQ(small[0].properties.size(), 4u);
  EXPECT_EQ(small[0].properties[0].type, 'L');
  EXPECT_EQ(small[0].properties[0].i, 1);
  EXPECT_EQ(small[0].properties[1].type, 'D');
  EXPECT_EQ(small[0].properties[1].d, -0.25);
  EXPECT_EQ(small[0].properties[2].s, "a\"b");
  EXPECT_EQ(small[0].properties[3].s, "T");
  ASSERT_EQ(small[1].properties.size(), 2u);
  EXPECT_EQ(small[1].properties[1].i, 8);
  ASSERT_EQ(small[1].children.size(), 2u);
  EXPECT_TRUE(small[1].children[0].properties.empty());
  ASSERT_EQ(small[1].children[1].properties.size(), 1u);
  EXPECT_EQ(small[1].children[1].properties[0].s, "x");
}

// Blender writes FBX in centimetres (UnitScaleFactor 1: one unit is 1 cm,
// every node scaled by 100); the file's unit is applied on loading, so the
// scene is the size it is in Blender and in its glTF export: the camera at
// the same place, the 4 m plane at y = -1 spanning [-2, 2].
TEST(ForeignCameras, BlendersFbxSceneIsInMetresAsInBlender) {
  const SceneData fbx = load_scene_data(kBlender / "persp_camera.fbx");
  const SceneData gltf = load_scene_data(kBlender / "ortho_camera.glb");
  ASSERT_FALSE(fbx.positions.empty());
  Vec3 lo(1e30f), hi(-1e30f);
  for (const Vec3& p : fbx.positions) {
    lo = Vec3(std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z));
    hi = Vec3(std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z));
  }
  EXPECT_NEAR(lo.x, -2.0f, 1e-4f);
  EXPECT_NEAR(hi.x, 2.0f, 1e-4f);
  EXPECT_NEAR(lo.y, -1.0f, 1e-4f);
  EXPECT_NEAR(hi.y, -1.0f, 1e-4f);
  EXPECT_NEAR(lo.z, -2.0f, 1e-4f);
  EXPECT_NEAR(hi.z, 2.0f, 1e-4f);
  const CameraState a = camera_for_frame(scene_camera_spec(), gltf, 0);
  const CameraState b = camera_for_frame(scene_camera_spec(), fbx, 0);
  expect_same_pose(a, b, 1e-3f);
  // Blender's 50 mm lens on its 36 mm sensor, fitted to the 16:9 width:
  // vertically 2 atan(18 / 50 / (16 / 9)).
  EXPECT_NEAR(b.fov_deg, 2.0 * std::atan(18.0 / 50.0 / (16.0 / 9.0)) * 180.0 / M_PI, 0.01);
}

// Perspective cameras: Blender's Collada and FBX exports of the scene render
// as its glTF export does, pixel for pixel in view depth.
TEST(ForeignCameras, BlendersColladaAndFbxPerspectiveCamerasAreItsGltfCamera) {
  const FrameBuffers gltf = render_fixture("persp_camera.glb", 0.0f);
  for (const char* file : {"persp_camera.dae", "persp_camera.fbx"}) {
    SCOPED_TRACE(file);
    const FrameBuffers other = render_fixture(file, 0.0f);
    EXPECT_NEAR(other.camera.fov_deg, gltf.camera.fov_deg, 1e-3f);
    expect_same_depths(gltf, other);
  }
}

// Blender writes a Principled BSDF's Metallic as the FBX and Collada
// material's reflectivity: the materials of its three exports of one scene
// agree in base colour and metallic, and FBX also in roughness (Collada
// carries a Phong exponent instead).
TEST(BlenderFormats, ColladaAndFbxMaterialsCarryTheGltfOnesMetallic) {
  const SceneData gltf = load_scene_data(kBlender / "materials.glb");
  auto find = [](const SceneData& s, const std::string& name) -> const Material* {
    for (const Material& m : s.materials)
      if (m.name == name) return &m;
    return nullptr;
  };
  for (const char* file : {"materials.dae", "materials.fbx"}) {
    const SceneData other = load_scene_data(kBlender / file);
    for (const char* name : {"Material", "Metal"}) {
      const Material* a = find(gltf, name);
      const Material* b = find(other, name);
      ASSERT_NE(a, nullptr) << name;
      ASSERT_NE(b, nullptr) << file << " " << name;
      EXPECT_NEAR(b->base_color.x, a->base_color.x, 1e-5f) << file << " " << name;
      EXPECT_NEAR(b->base_color.y, a->base_color.y, 1e-5f) << file << " " << name;
      EXPECT_NEAR(b->base_color.z, a->base_color.z, 1e-5f) << file << " " << name;
      EXPECT_EQ(b->metallic, a->metallic) << file << " " << name;
      if (std::string(file) == "materials.fbx") {
        EXPECT_NEAR(b->roughness, a->roughness, 1e-5f) << name;
      }
    }
  }
  EXPECT_EQ(find(gltf, "Metal")->metallic, 1.0f);
  EXPECT_EQ(find(gltf, "Material")->metallic, 0.0f);
}

// Blender exports an object without a material as an <instance_geometry>
// without a <bind_material>; assimp 5.2 gives it the file's first material
// (here the cube's blue). It gets the grey diffuse surface Blender renders
// it in, and the meshes that have materials keep theirs.
TEST(BlenderFormats, AColladaMeshWithoutAMaterialIsGreyNotTheFirstMaterial) {
  EXPECT_EQ(collada_unbound_geometries(R"(<node><instance_geometry url="#A-mesh" name="A"/></node>
      <node><instance_geometry url="#B-mesh"><bind_material/></instance_geometry></node>
      <node><instance_geometry url="#C-mesh"></instance_geometry></node>
      <node><instance_geometry url="#B-mesh"/></node>)"),
            (std::set<std::string>{"A-mesh", "C-mesh"}));
  const SceneData dae = load_scene_data(kBlender / "materials.dae");
  int plane = 0, others = 0;
  for (size_t t = 0; t < dae.tri_material.size(); ++t) {
    // The plane: at y = -1 and 4 m wide (the cube's bottom face is at
    // y = -1 too, but 2 m wide).
    bool on_plane = true, wide = false;
    for (int k = 0; k < 3; ++k) {
      const Vec3& p = dae.positions[dae.indices[3 * t + k]];
      on_plane = on_plane && std::fabs(p.y + 1.0f) < 1e-4f;
      wide = wide || std::fabs(p.x) > 1.5f;
    }
    on_plane = on_plane && wide;
    const Material& m = dae.materials[dae.tri_material[t]];
    if (on_plane) {
      ++plane;
      EXPECT_EQ(m.name, "(no material)");
      EXPECT_EQ(m.base_color.x, 0.8f);
      EXPECT_EQ(m.base_color.z, 0.8f);
      EXPECT_EQ(m.metallic, 0.0f);
      EXPECT_EQ(m.specular, 0.0f);
    } else {
      ++others;
      EXPECT_TRUE(m.name == "Material" || m.name == "Metal") << m.name;
    }
  }
  EXPECT_EQ(plane, 2);  // the plane's two triangles
  EXPECT_GT(others, 12);
}

}  // namespace
}  // namespace dofarm::render
