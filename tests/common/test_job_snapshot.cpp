// The job as a value (common/job_snapshot.h, common/content_hash.h): content
// hashes against an independent implementation, the canonical spec read
// back, key differences, and job.json parsing that refuses what it must.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>

#include "common/content_hash.h"
#include "common/error.h"
#include "common/job_snapshot.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;

// Known answers from Python's hashlib.blake2b(data, digest_size=16).
TEST(ContentHash, MatchesBlake2b128) {
  EXPECT_EQ(content_hash(""), "cae66941d9efbd404e4d88758ea67670");
  EXPECT_EQ(content_hash("abc"), "cf4ab791c62b8d2b2109c90275287816");
  ContentHasher h;
  h.update("a");
  h.update("bc");
  EXPECT_EQ(h.hex(), "cf4ab791c62b8d2b2109c90275287816");
}

TEST(ContentHash, ReadsOnlyRegularFilesWithoutFollowingLinks) {
  const fs::path dir = fs::temp_directory_path() / ("dofarm_hash_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  { std::ofstream(dir / "f") << "abc"; }
  EXPECT_EQ(hash_regular_file(dir / "f").hash, "cf4ab791c62b8d2b2109c90275287816");
  EXPECT_EQ(hash_regular_file(dir / "f").size, 3u);
  fs::create_symlink(dir / "f", dir / "link");
  EXPECT_THROW(hash_regular_file(dir / "link"), RuntimeError);
  EXPECT_THROW(hash_regular_file("/dev/zero"), RuntimeError);
  EXPECT_THROW(hash_regular_file(dir), RuntimeError);
  EXPECT_THROW(read_regular_file(dir / "f", 2), RuntimeError);  // over the bound
  EXPECT_EQ(read_regular_file(dir / "f", 3), "abc");
  fs::remove_all(dir);
}

// Every bundled spec, written canonically and read back, is the same job:
// the canonical text of the read-back spec is the text itself.
TEST(JobSnapshot, CanonicalSpecReadsBackToTheSameJob) {
  const fs::path jobs = fs::path(DOFARM_SOURCE_DIR) / "jobs";
  int checked = 0;
  for (const fs::path& spec_path : {jobs / "cornell.toml", jobs / "courtyard.toml",
                                    jobs / "test/furnace.toml", jobs / "test/light_box.toml",
                                    jobs / "test/plane.toml"}) {
    SCOPED_TRACE(spec_path.string());
    JobSpec spec = load_job_spec(spec_path, {"buffers.reference_error=0.02", "seed=123456789"});
    const std::string env = spec.environment && !spec.environment->map.empty()
                                ? spec.environment->map.string()
                                : "";
    const std::string text = canonical_spec_toml(spec, spec.scene.string(), env);
    JobSpec back = parse_job_spec(text, spec_path);
    EXPECT_EQ(canonical_spec_toml(back, back.scene.string(), env), text);
    EXPECT_EQ(back.seed, spec.seed);
    EXPECT_EQ(back.reference_error, spec.reference_error);
    ASSERT_EQ(back.camera_keys.size(), spec.camera_keys.size());
    for (size_t i = 0; i < spec.camera_keys.size(); ++i) {
      EXPECT_EQ(back.camera_keys[i].focal_distance, spec.camera_keys[i].focal_distance);
      EXPECT_EQ(back.camera_keys[i].aperture, spec.camera_keys[i].aperture);
      EXPECT_EQ(back.camera_keys[i].fov_deg, spec.camera_keys[i].fov_deg);
    }
    ++checked;
  }
  EXPECT_EQ(checked, 5);
}

// The reference clamp is written only when set: jobs without it keep the
// snapshot (and content hash) they had; with it, it reads back.
TEST(JobSnapshot, ReferenceClampIsWrittenOnlyWhenSet) {
  const fs::path spec_path = fs::path(DOFARM_SOURCE_DIR) / "jobs" / "cornell.toml";
  JobSpec plain = load_job_spec(spec_path);
  const std::string text = canonical_spec_toml(plain, plain.scene.string(), "");
  EXPECT_EQ(text.find("reference_clamp"), std::string::npos);
  JobSpec clamped = load_job_spec(spec_path, {"buffers.reference_clamp=20"});
  const std::string with = canonical_spec_toml(clamped, clamped.scene.string(), "");
  EXPECT_NE(with.find("reference_clamp = 20"), std::string::npos) << with;
  EXPECT_EQ(parse_job_spec(with, spec_path).reference_clamp, 20.0f);
}

// So are the lamp sizes ([lights]).
TEST(JobSnapshot, LampSizesAreWrittenOnlyWhenSet) {
  const fs::path spec_path = fs::path(DOFARM_SOURCE_DIR) / "jobs" / "cornell.toml";
  JobSpec plain = load_job_spec(spec_path);
  EXPECT_EQ(canonical_spec_toml(plain, plain.scene.string(), "").find("[lights]"),
            std::string::npos);
  JobSpec sized = load_job_spec(spec_path, {"lights.radius=0.25", "lights.sun_angle=0.5"});
  const std::string with = canonical_spec_toml(sized, sized.scene.string(), "");
  EXPECT_NE(with.find("[lights]\nradius = 0.25\nsun_angle = 0.5"), std::string::npos) << with;
  const JobSpec back = parse_job_spec(with, spec_path);
  EXPECT_EQ(back.light_radius, 0.25f);
  EXPECT_EQ(back.sun_angle_deg, 0.5f);
  JobSpec radius_only = load_job_spec(spec_path, {"lights.radius=0.1"});
  const std::string one = canonical_spec_toml(radius_only, radius_only.scene.string(), "");
  EXPECT_NE(one.find("radius = 0.1"), std::string::npos) << one;
  EXPECT_EQ(one.find("sun_angle"), std::string::npos) << one;
  // One lamp by name, read back as written.
  JobSpec by_name = load_job_spec(spec_path);
  by_name.lamp_sizes.push_back({"Light.001", 0.1f, -1.0f, 0});
  by_name.lamp_sizes.push_back({"Sun", -1.0f, 2.5f, 1});
  const std::string named = canonical_spec_toml(by_name, by_name.scene.string(), "");
  const JobSpec named_back = parse_job_spec(named, spec_path);
  ASSERT_EQ(named_back.lamp_sizes.size(), 2u) << named;
  EXPECT_EQ(named_back.lamp_sizes[0].name, "Light.001");
  EXPECT_EQ(named_back.lamp_sizes[0].radius, 0.1f);
  EXPECT_LT(named_back.lamp_sizes[0].sun_angle_deg, 0.0f);
  EXPECT_EQ(named_back.lamp_sizes[1].sun_angle_deg, 2.5f);
  EXPECT_EQ(canonical_spec_toml(named_back, by_name.scene.string(), ""), named);
}

// So is the scene camera's name: a job without it keeps its hash.
TEST(JobSnapshot, CameraNameIsWrittenOnlyWhenSet) {
  const fs::path spec_path = fs::path(DOFARM_SOURCE_DIR) / "jobs" / "courtyard.toml";
  JobSpec first = load_job_spec(spec_path);
  const std::string without =
      canonical_spec_toml(first, first.scene.string(), first.environment->map.string());
  EXPECT_EQ(without.find("name ="), std::string::npos) << without;
  JobSpec named = load_job_spec(spec_path, {"camera.name=Closeup"});
  EXPECT_EQ(named.camera_name, "Closeup");
  named.camera_name = "Closeup \"2\"";  // written quoted, read back as it was
  const std::string with =
      canonical_spec_toml(named, named.scene.string(), named.environment->map.string());
  EXPECT_NE(with.find("[camera]\nfrom_scene = true\nname = \"Closeup \\\"2\\\"\""),
            std::string::npos)
      << with;
  const JobSpec back = parse_job_spec(with, spec_path);
  EXPECT_EQ(back.camera_name, "Closeup \"2\"");
  EXPECT_EQ(canonical_spec_toml(back, back.scene.string(), back.environment->map.string()), with);
}

// The display-space stopping rule changes the references, so it is part of
// the job's content; a job without it keeps the snapshot it had before.
TEST(JobSnapshot, ReferenceDisplayErrorIsWrittenOnlyWhenSet) {
  const fs::path spec_path = fs::path(DOFARM_SOURCE_DIR) / "jobs" / "cornell.toml";
  JobSpec relative = load_job_spec(spec_path, {"buffers.reference_error=0.01"});
  const std::string without = canonical_spec_toml(relative, relative.scene.string(), "");
  EXPECT_EQ(without.find("reference_display_error"), std::string::npos) << without;
  JobSpec display = load_job_spec(
      spec_path, {"buffers.reference_error=0.01", "buffers.reference_display_error=0.002"});
  const std::string with = canonical_spec_toml(display, display.scene.string(), "");
  EXPECT_NE(with.find("reference_display_error = 0.002"), std::string::npos) << with;
  EXPECT_NE(with, without);
  const JobSpec back = parse_job_spec(with, spec_path);
  EXPECT_EQ(back.reference_display_error, 0.002f);
  EXPECT_EQ(canonical_spec_toml(back, back.scene.string(), ""), with);
}

TEST(JobSnapshot, DifferencesNameEachChangedKey) {
  const fs::path spec_path = fs::path(DOFARM_SOURCE_DIR) / "jobs/cornell.toml";
  JobSpec a = load_job_spec(spec_path);
  JobSpec b = load_job_spec(spec_path, {"seed=8", "frames.end=31", "camera.key.1.aperture=0.1"});
  const auto diff = spec_differences(canonical_spec_toml(a, "files/s.gltf", ""),
                                     canonical_spec_toml(b, "files/s.gltf", ""));
  EXPECT_EQ(diff, (std::vector<std::string>{"camera.key.1.aperture: 0.08 -> 0.1",
                                            "frames.end: 95 -> 31", "seed: 7 -> 8"}));
  EXPECT_TRUE(spec_differences(canonical_spec_toml(a, "x", ""), canonical_spec_toml(a, "x", ""))
                  .empty());
}

JobSnapshot sample() {
  JobSnapshot s;
  s.spec_toml = "scene = \"files/a.gltf\"\n";
  s.inputs = {{"files/a.bin", 10, std::string(32, 'a')}, {"files/a.gltf", 5, std::string(32, 'b')}};
  s.source_spec = "/jobs/a.toml";
  s.source_overrides = {"seed=1"};
  return s;
}

TEST(JobSnapshot, HashIsOfContentNotOfSourceOrLayout) {
  JobSnapshot s = sample();
  const std::string h = s.hash();
  EXPECT_TRUE(is_content_hash(h));
  JobSnapshot moved = s;
  moved.source_spec = "/elsewhere/b.toml";
  moved.source_overrides.clear();
  EXPECT_EQ(moved.hash(), h);
  EXPECT_EQ(JobSnapshot::from_json(s.to_json(), "t").hash(), h);
  EXPECT_EQ(JobSnapshot::from_json(s.to_json(-1), "t").hash(), h);
  JobSnapshot other = s;
  other.inputs[0].hash[0] = 'c';
  EXPECT_NE(other.hash(), h);
  other = s;
  other.spec_toml += "seed = 1\n";
  EXPECT_NE(other.hash(), h);
}

TEST(JobSnapshot, ParsingRefusesPathsOutOfTheJobFolderAndMalformedInputs) {
  auto with = [](const std::function<void(nlohmann::json&)>& change) {
    nlohmann::json j = nlohmann::json::parse(sample().to_json());
    change(j);
    return j.dump();
  };
  using J = nlohmann::json;
  const std::vector<std::string> bad = {
      "", "[]", "{}",
      with([](J& j) { j["schema"] = "dofarm.job/9"; }),
      with([](J& j) { j["inputs"][0]["path"] = "files/../../etc/passwd"; }),
      with([](J& j) { j["inputs"][0]["path"] = "/etc/passwd"; }),
      with([](J& j) { j["inputs"][0]["path"] = "other/a.bin"; }),
      with([](J& j) { j["inputs"][0]["hash"] = "xyz"; }),
      with([](J& j) { j["inputs"][0]["size"] = -1; }),
      with([](J& j) { std::swap(j["inputs"][0], j["inputs"][1]); }),  // unsorted
      with([](J& j) { j["inputs"][1] = j["inputs"][0]; }),            // duplicate
      with([](J& j) { j["spec"] = 5; }),
  };
  for (const std::string& text : bad) EXPECT_THROW(JobSnapshot::from_json(text, "t"), RuntimeError) << text;
}

}  // namespace
}  // namespace dofarm
