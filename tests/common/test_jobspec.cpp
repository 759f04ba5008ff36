// Job spec parsing: every bad spec of the corpus fails with its exact location
// and key; good specs get the struct's defaults, resolved paths, sorted camera
// keys; --set overrides are checked like the file and located at the --set.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

#include "common/error.h"
#include "common/job_snapshot.h"
#include "common/jobspec.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------
// The bad-spec corpus: tests/data/bad_specs/*.toml, each starting with
//   # expect: LINE:COL: "dotted.key": message fragment
// (LINE:COL and the key are left out where the error has none).

struct BadSpec {
  fs::path path;
  int line = 0, column = 0;
  std::string key;
  std::string fragment;
};

// gtest prints the parameter of a failing case: the file name says it all.
void PrintTo(const BadSpec& spec, std::ostream* os) { *os << spec.path.filename(); }

std::vector<BadSpec> load_corpus() {
  std::vector<BadSpec> out;
  const fs::path dir = fs::path(DOFARM_TEST_DATA) / "bad_specs";
  static const std::regex kExpect(R"re(^# expect: (?:(\d+):(\d+): )?(?:"([^"]*)": )?(.+)$)re");
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().extension() != ".toml") continue;
    std::ifstream in(entry.path());
    std::string first;
    std::getline(in, first);
    std::smatch m;
    BadSpec spec;
    spec.path = entry.path();
    if (!std::regex_match(first, m, kExpect)) {
      spec.fragment = "<malformed expect line: " + first + ">";
    } else {
      if (m[1].matched) {
        spec.line = std::stoi(m[1]);
        spec.column = std::stoi(m[2]);
      }
      spec.key = m[3];
      spec.fragment = m[4];
    }
    out.push_back(spec);
  }
  std::sort(out.begin(), out.end(),
            [](const BadSpec& a, const BadSpec& b) { return a.path < b.path; });
  return out;
}

class BadSpecCorpus : public testing::TestWithParam<BadSpec> {};

TEST_P(BadSpecCorpus, FailsWithExpectedLocationAndKey) {
  const BadSpec& bad = GetParam();
  ASSERT_EQ(bad.fragment.find("<malformed"), std::string::npos) << bad.fragment;
  try {
    load_job_spec(bad.path);
    FAIL() << bad.path << " was accepted";
  } catch (const SpecError& e) {
    const std::string what = e.what();
    EXPECT_EQ(e.loc().file, bad.path.string());
    EXPECT_EQ(e.loc().line, bad.line) << what;
    EXPECT_EQ(e.loc().column, bad.column) << what;
    EXPECT_EQ(e.key(), bad.key) << what;
    std::string prefix = FileLoc{bad.path.string(), bad.line, bad.column}.str() + ": ";
    if (!bad.key.empty()) prefix += "\"" + bad.key + "\": ";
    EXPECT_EQ(what.rfind(prefix, 0), 0u) << "expected prefix: " << prefix << "\ngot: " << what;
    EXPECT_NE(what.find(bad.fragment, prefix.size()), std::string::npos)
        << "expected fragment: " << bad.fragment << "\ngot: " << what;
  }
}

INSTANTIATE_TEST_SUITE_P(JobSpec, BadSpecCorpus, testing::ValuesIn(load_corpus()),
                         [](const testing::TestParamInfo<BadSpec>& info) {
                           return info.param.path.stem().string();
                         });

TEST(BadSpecCorpusSize, HasAtLeast25Specs) { EXPECT_GE(load_corpus().size(), 25u); }

// ---------------------------------------------------------------------------
// Good specs, written into a fresh folder with placeholder scene files (the
// parser only checks that they exist).

class JobSpecFiles : public testing::Test {
 protected:
  void SetUp() override {
    const auto* info = testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(testing::TempDir()) / (std::string("dofarm_jobspec_") + info->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    touch("scene.gltf");
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path touch(const std::string& rel) {
    fs::path p = dir_ / rel;
    fs::create_directories(p.parent_path());
    std::ofstream(p) << "placeholder\n";
    return p;
  }
  fs::path write(const std::string& rel, const std::string& text) {
    fs::path p = dir_ / rel;
    fs::create_directories(p.parent_path());
    std::ofstream(p) << text;
    return p;
  }
  // Parses `text` as dir_/job.toml.
  JobSpec parse(const std::string& text, const std::vector<std::string>& overrides = {}) {
    return parse_job_spec(text, dir_ / "job.toml", overrides);
  }
  // The SpecError that parsing throws; fails the test if none is thrown.
  SpecError parse_error(const std::string& text, const std::vector<std::string>& overrides = {}) {
    try {
      parse(text, overrides);
    } catch (const SpecError& e) {
      return e;
    }
    ADD_FAILURE() << "spec was accepted";
    return SpecError(FileLoc{}, "", "none");
  }

  fs::path dir_;
};

const char* kOneKey = R"(scene = "scene.gltf"
[[camera.key]]
position = [0.0, 1.0, 4.0]
look_at = [0.0, 1.0, 0.0]
)";

TEST_F(JobSpecFiles, MinimalSpecGetsTheStructDefaults) {
  JobSpec spec = parse(kOneKey);
  const JobSpec d;
  EXPECT_EQ(spec.scene, dir_ / "scene.gltf");
  EXPECT_EQ(spec.spec_path, dir_ / "job.toml");
  EXPECT_EQ(spec.seed, d.seed);
  EXPECT_EQ(spec.width, d.width);
  EXPECT_EQ(spec.height, d.height);
  EXPECT_EQ(spec.frame_start, d.frame_start);
  EXPECT_EQ(spec.frame_end, d.frame_end);
  EXPECT_EQ(spec.per_shard, d.per_shard);
  EXPECT_EQ(spec.fps, d.fps);
  EXPECT_FALSE(spec.camera_from_scene);
  EXPECT_FALSE(spec.environment.has_value());
  EXPECT_EQ(spec.versions, d.versions);
  EXPECT_EQ(spec.reference_spp, d.reference_spp);
  EXPECT_EQ(spec.reference_error, d.reference_error);
  EXPECT_EQ(spec.reference_max_spp, d.reference_max_spp);
  EXPECT_EQ(spec.albedo_ref_spp, d.albedo_ref_spp);
  EXPECT_EQ(spec.max_depth, d.max_depth);
  EXPECT_EQ(spec.rr_start_depth, d.rr_start_depth);
  EXPECT_EQ(spec.sampler, d.sampler);
  EXPECT_EQ(spec.tile, d.tile);
  EXPECT_EQ(spec.task_seconds, d.task_seconds);

  ASSERT_EQ(spec.camera_keys.size(), 1u);
  const CameraKey& k = spec.camera_keys[0];
  const CameraKey dk;
  EXPECT_EQ(k.frame, dk.frame);
  EXPECT_EQ(k.position.z, 4.0f);
  ASSERT_TRUE(k.look_at.has_value());
  EXPECT_EQ(k.look_at->y, 1.0f);
  EXPECT_FALSE(k.rotation_deg.has_value());
  EXPECT_EQ(k.up.y, dk.up.y);
  EXPECT_EQ(k.fov_deg, dk.fov_deg);
  EXPECT_EQ(k.focal_distance, dk.focal_distance);
  EXPECT_EQ(k.aperture, dk.aperture);
}

TEST_F(JobSpecFiles, EveryKeyIsRead) {
  touch("sky.exr");
  JobSpec spec = parse(R"(scene = "scene.gltf"
seed = 123456789012
[image]
width = 320
height = 200
[frames]
start = 5
end = 9
per_shard = 3
fps = 30
[[camera.key]]
frame = 5
position = [1, 2, 3]
look_at = [0, 0, 0]
up = [0, 0, 1]
fov = 55.5
focal_distance = 2.5
aperture = 0.125
[environment]
map = "sky.exr"
intensity = 2.0
rotation = -90
[buffers]
versions = 4
reference_error = 0.02
reference_max_spp = 4096
reference_display_error = 0.0025
albedo_ref_spp = 8
[render]
max_depth = 7
rr_start_depth = 2
sampler = "independent"
[farm]
task_seconds = 45.0
)");
  EXPECT_EQ(spec.seed, 123456789012u);
  EXPECT_EQ(spec.width, 320);
  EXPECT_EQ(spec.height, 200);
  EXPECT_EQ(spec.frame_start, 5);
  EXPECT_EQ(spec.frame_end, 9);
  EXPECT_EQ(spec.frame_count(), 5);
  EXPECT_EQ(spec.per_shard, 3);
  EXPECT_EQ(spec.fps, 30.0f);
  ASSERT_EQ(spec.camera_keys.size(), 1u);
  const CameraKey& k = spec.camera_keys[0];
  EXPECT_EQ(k.frame, 5);
  EXPECT_EQ(k.position.x, 1.0f);
  EXPECT_EQ(k.position.y, 2.0f);
  EXPECT_EQ(k.position.z, 3.0f);
  EXPECT_EQ(k.up.z, 1.0f);
  EXPECT_EQ(k.fov_deg, 55.5f);
  EXPECT_EQ(k.focal_distance, 2.5f);
  EXPECT_EQ(k.aperture, 0.125f);
  ASSERT_TRUE(spec.environment.has_value());
  EXPECT_EQ(spec.environment->map, dir_ / "sky.exr");
  EXPECT_FALSE(spec.environment->color.has_value());
  EXPECT_EQ(spec.environment->intensity, 2.0f);
  EXPECT_EQ(spec.environment->rotation_deg, -90.0f);
  EXPECT_EQ(spec.versions, 4);
  EXPECT_EQ(spec.reference_error, 0.02f);
  EXPECT_EQ(spec.reference_max_spp, 4096);
  EXPECT_EQ(spec.reference_display_error, 0.0025f);
  EXPECT_EQ(spec.albedo_ref_spp, 8);
  EXPECT_EQ(spec.max_depth, 7);
  EXPECT_EQ(spec.rr_start_depth, 2);
  EXPECT_EQ(spec.sampler, SamplerKind::kIndependent);
  EXPECT_EQ(spec.task_seconds, 45.0f);
}

TEST_F(JobSpecFiles, RelativePathsResolveAgainstTheSpecFolder) {
  touch("scenes/room.gltf");
  touch("assets/hdri/sky.exr");
  fs::path spec_path = write("jobs/nested/job.toml", R"(scene = "../../scenes/room.gltf"
[[camera.key]]
rotation = [0, 0, 0]
[environment]
map = "../../assets/hdri/sky.exr"
)");
  JobSpec spec = load_job_spec(spec_path);
  EXPECT_EQ(spec.scene, dir_ / "scenes/room.gltf");
  EXPECT_TRUE(spec.scene.is_absolute());
  EXPECT_EQ(spec.environment->map, dir_ / "assets/hdri/sky.exr");
  EXPECT_EQ(spec.spec_path, spec_path);
}

TEST_F(JobSpecFiles, MissingSceneNamesKeyAndResolvedPath) {
  SpecError e = parse_error(R"(scene = "scenes/nope.gltf")");
  EXPECT_EQ(e.key(), "scene");
  EXPECT_EQ(e.loc().line, 1);
  EXPECT_EQ(e.loc().column, 9);
  EXPECT_NE(std::string(e.what()).find((dir_ / "scenes/nope.gltf").string()), std::string::npos)
      << e.what();
}

TEST_F(JobSpecFiles, MissingSpecFileIsBadInput) {
  try {
    load_job_spec(dir_ / "absent.toml");
    FAIL();
  } catch (const SpecError& e) {
    EXPECT_EQ(e.loc().file, (dir_ / "absent.toml").string());
    EXPECT_NE(std::string(e.what()).find("file not found"), std::string::npos) << e.what();
  }
}

TEST_F(JobSpecFiles, CameraKeysAreSortedByFrame) {
  JobSpec spec = parse(R"(scene = "scene.gltf"
[[camera.key]]
frame = 48
rotation = [0, 0, 0]
aperture = 0.48
focal_distance = 4.8
[[camera.key]]
frame = 0
rotation = [0, 0, 0]
aperture = 0.0
focal_distance = 1
[[camera.key]]
frame = 95
rotation = [0, 0, 0]
aperture = 0.95
focal_distance = 9.5
)");
  ASSERT_EQ(spec.camera_keys.size(), 3u);
  EXPECT_EQ(spec.camera_keys[0].frame, 0);
  EXPECT_EQ(spec.camera_keys[1].frame, 48);
  EXPECT_EQ(spec.camera_keys[2].frame, 95);
  // The keys move with their frames, not just the frame numbers.
  EXPECT_EQ(spec.camera_keys[0].aperture, 0.0f);
  EXPECT_EQ(spec.camera_keys[1].aperture, 0.48f);
  EXPECT_EQ(spec.camera_keys[2].aperture, 0.95f);
  EXPECT_EQ(spec.camera_keys[2].focal_distance, 9.5f);
  EXPECT_TRUE(spec.camera_keys[1].rotation_deg.has_value());
  EXPECT_FALSE(spec.camera_keys[1].look_at.has_value());
}

TEST_F(JobSpecFiles, EnvironmentColourInsteadOfMap) {
  JobSpec spec = parse(std::string(kOneKey) + "[environment]\ncolor = [0.5, 0.25, 1]\n");
  ASSERT_TRUE(spec.environment.has_value());
  EXPECT_TRUE(spec.environment->map.empty());
  ASSERT_TRUE(spec.environment->color.has_value());
  EXPECT_EQ(spec.environment->color->y, 0.25f);
}

// ---------------------------------------------------------------------------
// camera.from_scene

TEST_F(JobSpecFiles, FromSceneWithoutKeysIsAPinhole) {
  JobSpec spec = parse("scene = \"scene.gltf\"\n[camera]\nfrom_scene = true\n");
  EXPECT_TRUE(spec.camera_from_scene);
  EXPECT_TRUE(spec.camera_keys.empty());
}

TEST_F(JobSpecFiles, FromSceneKeysCarryOnlyTheLens) {
  JobSpec spec = parse(R"(scene = "scene.gltf"
[camera]
from_scene = true
[[camera.key]]
frame = 24
focal_distance = 3.4
aperture = 0.08
[[camera.key]]
frame = 0
focal_distance = 9
)");
  ASSERT_EQ(spec.camera_keys.size(), 2u);
  EXPECT_EQ(spec.camera_keys[0].frame, 0);
  EXPECT_EQ(spec.camera_keys[0].focal_distance, 9.0f);
  EXPECT_EQ(spec.camera_keys[0].aperture, 0.0f);
  EXPECT_EQ(spec.camera_keys[1].aperture, 0.08f);
  EXPECT_FALSE(spec.camera_keys[1].look_at.has_value());
  EXPECT_FALSE(spec.camera_keys[1].rotation_deg.has_value());
}

TEST_F(JobSpecFiles, FromSceneRefusesFovAndLookAt) {
  for (const char* key : {"fov = 40", "look_at = [0, 0, 0]", "rotation = [0, 0, 0]"}) {
    SpecError e = parse_error(std::string("scene = \"scene.gltf\"\n[camera]\nfrom_scene = true\n"
                                          "[[camera.key]]\n") +
                              key + "\n");
    EXPECT_EQ(e.loc().line, 5) << e.what();
    EXPECT_NE(std::string(e.what()).find("camera.from_scene = true"), std::string::npos)
        << e.what();
  }
}

// camera.name picks one of the scene's cameras: only with from_scene, and
// never empty.
TEST_F(JobSpecFiles, CameraNameNeedsFromSceneAndANonEmptyName) {
  JobSpec spec = parse("scene = \"scene.gltf\"\n[camera]\nfrom_scene = true\nname = \"Closeup\"\n");
  EXPECT_EQ(spec.camera_name, "Closeup");
  EXPECT_TRUE(parse("scene = \"scene.gltf\"\n[camera]\nfrom_scene = true\n").camera_name.empty());
  SpecError alone = parse_error(
      "scene = \"scene.gltf\"\n[camera]\nname = \"Closeup\"\n[[camera.key]]\nposition = [0, 0, "
      "5]\nlook_at = [0, 0, 0]\n");
  EXPECT_EQ(alone.key(), "camera.name");
  EXPECT_EQ(alone.loc().line, 3);
  EXPECT_NE(std::string(alone.what()).find("only with camera.from_scene = true"), std::string::npos)
      << alone.what();
  SpecError empty =
      parse_error("scene = \"scene.gltf\"\n[camera]\nfrom_scene = true\nname = \"\"\n");
  EXPECT_EQ(empty.key(), "camera.name");
  EXPECT_EQ(empty.loc().line, 4);
}

TEST_F(JobSpecFiles, WithoutFromSceneAKeyIsRequired) {
  SpecError e = parse_error("scene = \"scene.gltf\"\n");
  EXPECT_EQ(e.key(), "camera.key");
  EXPECT_EQ(e.loc().line, 0);  // nothing in the file to point at
}

// ---------------------------------------------------------------------------
// --set overrides

TEST_F(JobSpecFiles, OverridesSetValuesOfEveryKind) {
  touch("hdri/sky.exr");
  JobSpec spec =
      parse(kOneKey, {"image.width=64", "buffers.reference_spp=16", "camera.key.0.aperture=0.1",
                      "camera.key.0.focal_distance=2.5", "camera.key.0.position=[1, 2, 3]",
                      "environment.map=hdri/sky.exr", "render.sampler=independent", "seed=99"});
  EXPECT_EQ(spec.width, 64);
  EXPECT_EQ(spec.reference_spp, 16);
  EXPECT_EQ(spec.camera_keys[0].aperture, 0.1f);
  EXPECT_EQ(spec.camera_keys[0].position.z, 3.0f);
  ASSERT_TRUE(spec.environment.has_value());
  EXPECT_EQ(spec.environment->map, dir_ / "hdri/sky.exr");  // relative to the spec, not cwd
  EXPECT_EQ(spec.sampler, SamplerKind::kIndependent);
  EXPECT_EQ(spec.seed, 99u);
}

TEST_F(JobSpecFiles, OverrideQuotedStringAndBareWordAgree) {
  touch("my scene.gltf");
  JobSpec a = parse(kOneKey, {"scene=\"my scene.gltf\""});
  JobSpec b = parse(kOneKey, {"scene=my scene.gltf"});
  EXPECT_EQ(a.scene, dir_ / "my scene.gltf");
  EXPECT_EQ(b.scene, a.scene);
}

TEST_F(JobSpecFiles, LaterOverrideWins) {
  JobSpec spec = parse(kOneKey, {"image.width=64", "image.width=32"});
  EXPECT_EQ(spec.width, 32);
}

TEST_F(JobSpecFiles, OverrideReplacesItsAlternative) {
  // The file asks for an error target; --set reference_spp switches to a fixed spp.
  std::string text = std::string(kOneKey) +
                     "[buffers]\nreference_error = 0.01\n"
                     "reference_max_spp = 512\n"
                     "reference_display_error = 0.002\n";
  JobSpec spec = parse(text, {"buffers.reference_spp=16"});
  EXPECT_EQ(spec.reference_spp, 16);
  EXPECT_EQ(spec.reference_error, 0.0f);
  EXPECT_EQ(spec.reference_max_spp, JobSpec{}.reference_max_spp);
  EXPECT_EQ(spec.reference_display_error, 0.0f);
  // Setting the display rule keeps the file's error target: same group.
  JobSpec display = parse(text, {"buffers.reference_display_error=0.003"});
  EXPECT_EQ(display.reference_error, 0.01f);
  EXPECT_EQ(display.reference_max_spp, 512);
  EXPECT_EQ(display.reference_display_error, 0.003f);

  JobSpec rotated = parse(kOneKey, {"camera.key.0.rotation=[0, 45, 0]"});
  EXPECT_FALSE(rotated.camera_keys[0].look_at.has_value());
  EXPECT_EQ(rotated.camera_keys[0].rotation_deg->y, 45.0f);
}

TEST_F(JobSpecFiles, BadOverrideValueIsLocatedAtTheSet) {
  SpecError e = parse_error(kOneKey, {"image.width=-4"});
  EXPECT_STREQ(e.what(),
               "--set image.width=-4: \"image.width\": expected an integer in [1, 16384], got -4");
  EXPECT_EQ(e.loc().file, "--set image.width=-4");
  EXPECT_EQ(e.loc().line, 0);

  SpecError nan = parse_error(kOneKey, {"camera.key.0.aperture=nan"});
  EXPECT_EQ(nan.loc().file, "--set camera.key.0.aperture=nan");
  EXPECT_EQ(nan.key(), "camera.key.0.aperture");
  EXPECT_NE(std::string(nan.what()).find("finite"), std::string::npos);
}

// The reference clamp (opt-in, biased): off (0) unless set; a positive
// number; zero, negative or not a number is an error naming the key.
TEST_F(JobSpecFiles, ReferenceClampIsOptInAndPositive) {
  EXPECT_EQ(parse(kOneKey).reference_clamp, 0.0f);
  EXPECT_EQ(parse(kOneKey, {"buffers.reference_clamp=12.5"}).reference_clamp, 12.5f);
  for (const char* bad :
       {"buffers.reference_clamp=0", "buffers.reference_clamp=-1", "buffers.reference_clamp=inf"}) {
    SCOPED_TRACE(bad);
    SpecError e = parse_error(kOneKey, {bad});
    EXPECT_EQ(e.key(), "buffers.reference_clamp");
    const std::string what = e.what();
    EXPECT_TRUE(what.find("a positive number") != std::string::npos ||
                what.find("a finite number") != std::string::npos)
        << what;
  }
}

// Lamp sizes (glTF does not carry Blender's): 0 (points, parallel light)
// unless set; a radius in [0, 1e6] scene units and an angle in [0, 180]
// degrees; anything else, or an unknown key of [lights], is an error naming
// the key.
TEST_F(JobSpecFiles, LampSizesAreOptInAndBounded) {
  EXPECT_EQ(parse(kOneKey).light_radius, 0.0f);
  EXPECT_EQ(parse(kOneKey).sun_angle_deg, 0.0f);
  const JobSpec s = parse(kOneKey, {"lights.radius=0.25", "lights.sun_angle=0.526"});
  EXPECT_EQ(s.light_radius, 0.25f);
  EXPECT_EQ(s.sun_angle_deg, 0.526f);
  for (const char* bad :
       {"lights.radius=-1", "lights.radius=inf", "lights.radius=2e6", "lights.sun_angle=-0.5",
        "lights.sun_angle=181", "lights.sun_angle=nan"}) {
    SCOPED_TRACE(bad);
    SpecError e = parse_error(kOneKey, {bad});
    EXPECT_EQ(e.key(), std::string(bad).substr(0, std::string(bad).find('=')));
  }
  SpecError e = parse_error(kOneKey, {"lights.size=1"});
  EXPECT_NE(std::string(e.what()).find("size"), std::string::npos) << e.what();
}

// [[lights.lamp]]: one lamp's size by name, over the table's own; a name is
// required, so is one of the sizes, and a name may be sized once.
TEST_F(JobSpecFiles, LampsAreSizedOneByOneByName) {
  const std::string text = std::string(kOneKey) +
                           "\n[lights]\nradius = 0.25\n"
                           "[[lights.lamp]]\nname = \"Light.001\"\nradius = 0.1\n"
                           "[[lights.lamp]]\nname = \"Sun\"\nsun_angle = 2.5\n";
  const JobSpec s = parse(text);
  EXPECT_EQ(s.light_radius, 0.25f);
  ASSERT_EQ(s.lamp_sizes.size(), 2u);
  EXPECT_EQ(s.lamp_sizes[0].name, "Light.001");
  EXPECT_EQ(s.lamp_sizes[0].radius, 0.1f);
  EXPECT_LT(s.lamp_sizes[0].sun_angle_deg, 0.0f);  // not given
  EXPECT_EQ(s.lamp_sizes[1].name, "Sun");
  EXPECT_EQ(s.lamp_sizes[1].sun_angle_deg, 2.5f);
  EXPECT_EQ(s.lamp_sizes[1].index, 1);
  // --set reaches an entry like a camera key.
  EXPECT_EQ(parse(text, {"lights.lamp.0.radius=0.3"}).lamp_sizes[0].radius, 0.3f);
  const struct {
    const char* extra;
    const char* key;
  } bad[] = {
      {"\n[[lights.lamp]]\nradius = 0.1\n", "lights.lamp.0.name"},
      {"\n[[lights.lamp]]\nname = \"Key\"\n", "lights.lamp.0"},
      {"\n[[lights.lamp]]\nname = \"Key\"\nradius = -1\n", "lights.lamp.0.radius"},
      {"\n[[lights.lamp]]\nname = \"Key\"\nsun_angle = 200\n", "lights.lamp.0.sun_angle"},
      {"\n[[lights.lamp]]\nname = \"Key\"\nsize = 1\n", "lights.lamp.0.size"},
      {"\n[[lights.lamp]]\nname = \"Key\"\nradius = 0.1\n"
       "[[lights.lamp]]\nname = \"Key\"\nradius = 0.2\n",
       "lights.lamp.1.name"},
  };
  for (const auto& b : bad) {
    SCOPED_TRACE(b.extra);
    SpecError e = parse_error(std::string(kOneKey) + b.extra);
    EXPECT_EQ(e.key(), b.key) << e.what();
  }
}

TEST_F(JobSpecFiles, OverrideOfUnknownKeyIsAnError) {
  SpecError e = parse_error(kOneKey, {"image.widht=64"});
  EXPECT_EQ(e.loc().file, "--set image.widht=64");
  EXPECT_EQ(e.key(), "image.widht");
  EXPECT_NE(std::string(e.what()).find("unknown key"), std::string::npos);

  SpecError table = parse_error(kOneKey, {"imgae.width=64"});
  EXPECT_EQ(table.key(), "imgae");
  EXPECT_NE(std::string(table.what()).find("unknown key"), std::string::npos);
}

TEST_F(JobSpecFiles, MalformedOverridesAreLocated) {
  struct Case {
    const char* set;
    const char* key;
    const char* fragment;
  };
  for (const Case& c : {
           Case{"image.width", "", "expected KEY=VALUE"},
           Case{"=3", "", "empty key"},
           Case{"image..width=3", "image..width", "empty part"},
           Case{"camera.key.3.aperture=0.1", "camera.key.3", "out of range"},
           Case{"camera.key.first.aperture=0.1", "camera.key.first", "element index"},
           Case{"scene.x=1", "scene", "not a table"},
           Case{"frames.list.0=1", "frames.list", "no such array"},
       }) {
    SpecError e = parse_error(kOneKey, {c.set});
    EXPECT_EQ(e.loc().file, std::string("--set ") + c.set);
    EXPECT_EQ(e.key(), c.key) << e.what();
    EXPECT_NE(std::string(e.what()).find(c.fragment), std::string::npos) << e.what();
  }
}

TEST_F(JobSpecFiles, OverrideMakingDuplicateFramesBlamesTheSet) {
  std::string two = std::string(kOneKey) + "[[camera.key]]\nframe = 10\nrotation = [0, 0, 0]\n";
  SpecError e = parse_error(two, {"camera.key.1.frame=0"});
  EXPECT_EQ(e.loc().file, "--set camera.key.1.frame=0");
  EXPECT_NE(std::string(e.what()).find("duplicate camera key for frame 0"), std::string::npos);
}

TEST_F(JobSpecFiles, SyntaxErrorIsLocated) {
  SpecError e = parse_error("scene = \"scene.gltf\"\nseed = = 3\n");
  EXPECT_EQ(e.loc().file, (dir_ / "job.toml").string());
  EXPECT_EQ(e.loc().line, 2);
  EXPECT_GT(e.loc().column, 0);
}

// ---------------------------------------------------------------------------
// Lens and focus keys

TEST_F(JobSpecFiles, LensAndFocusKeysAreReadAndWrittenBackCanonically) {
  JobSpec spec = parse(R"(scene = "scene.gltf"
[[camera.key]]
frame = 0
position = [0, 1, 4]
look_at = [0, 1, 0]
fstop = 2.8
focal_length = 50
focus_point = [0.5, 1, -0.25]
[[camera.key]]
frame = 10
position = [0, 1, 4]
look_at = [0, 1, 0]
fstop = 1.4
sensor_width = 23.5
focus = "auto"
[[camera.key]]
frame = 20
position = [0, 1, 4]
look_at = [0, 1, 0]
aperture = 0.02
focal_distance = 3
)");
  ASSERT_EQ(spec.camera_keys.size(), 3u);
  const CameraKey& a = spec.camera_keys[0];
  EXPECT_EQ(a.fstop, 2.8f);
  EXPECT_EQ(a.focal_length_mm, 50.0f);
  EXPECT_EQ(a.focus, FocusMode::kPoint);
  EXPECT_EQ(a.focus_point.z, -0.25f);
  EXPECT_TRUE(a.has_lens());
  const CameraKey& b = spec.camera_keys[1];
  EXPECT_EQ(b.fstop, 1.4f);
  EXPECT_EQ(b.focal_length_mm, 0.0f);  // from the fov, at render time
  EXPECT_EQ(b.sensor_width_mm, 23.5f);
  EXPECT_EQ(b.focus, FocusMode::kAuto);
  EXPECT_EQ(spec.camera_keys[2].focus, FocusMode::kDistance);
  EXPECT_EQ(spec.where("camera.key.1.focus").str(), (dir_ / "job.toml").string() + ":15:9");

  const std::string text = canonical_spec_toml(spec, "scene.gltf", "");
  for (const char* line :
       {"fstop = 2.8\nfocal_length = 50.0\n", "focus_point = [0.5, 1.0, -0.25]\n",
        "focus = \"auto\"\nfstop = 1.4\nsensor_width = 23.5\n",
        "focal_distance = 3.0\naperture = 0.02\n"})
    EXPECT_NE(text.find(line), std::string::npos) << line << " not in\n" << text;
  JobSpec back = parse_job_spec(text, dir_ / "job.toml");
  EXPECT_EQ(canonical_spec_toml(back, "scene.gltf", ""), text);
}

TEST_F(JobSpecFiles, PinholeKeysKeepTheirCanonicalText) {
  // Job hashes of pinhole specs written before the focus keys stay the same.
  const std::string text = canonical_spec_toml(parse(kOneKey), "s.gltf", "");
  EXPECT_NE(text.find("fov = 40.0\nfocal_distance = 1.0\naperture = 0.0\n"), std::string::npos)
      << text;
}

TEST_F(JobSpecFiles, OverrideSwitchesBetweenApertureAndFstop) {
  const std::string lens = std::string(kOneKey) + "aperture = 0.1\nfocal_distance = 2\n";
  JobSpec spec = parse(lens, {"camera.key.0.fstop=4", "camera.key.0.focus=auto"});
  EXPECT_EQ(spec.camera_keys[0].aperture, 0.0f);
  EXPECT_EQ(spec.camera_keys[0].fstop, 4.0f);
  EXPECT_EQ(spec.camera_keys[0].focus, FocusMode::kAuto);
  SpecError e = parse_error(kOneKey, {"camera.key.0.fstop=2"});
  EXPECT_EQ(e.key(), "camera.key.0.fstop");
  EXPECT_NE(e.message().find("needs a focus"), std::string::npos) << e.what();
}

TEST_F(JobSpecFiles, ImageSizeGivenIsRecordedForTheSceneCamera) {
  const std::string from_scene = "scene = \"scene.gltf\"\n[camera]\nfrom_scene = true\n";
  JobSpec none = parse(from_scene);
  EXPECT_FALSE(none.width_given);
  EXPECT_FALSE(none.height_given);
  EXPECT_EQ(none.where("camera.from_scene").str(), (dir_ / "job.toml").string() + ":3:14");
  JobSpec w = parse(from_scene + "[image]\nwidth = 1920\n");
  EXPECT_TRUE(w.width_given);
  EXPECT_FALSE(w.height_given);
  JobSpec both = parse(kOneKey, {"image.height=100", "image.width=50"});
  EXPECT_TRUE(both.width_given && both.height_given);
}

}  // namespace
}  // namespace dofarm
