// Issue 10, defects 1, 2, 3, 12 and the submit half of 6: a batch is one immutable job. The job is
// resolved once into a snapshot (spec, scene, buffers, textures, environment
// map, each by content hash), an output folder belongs to one job, workers
// render the snapshot and never re-read a path, and content errors are found
// before anything is written. Real processes on loopback throughout.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <regex>

#include "common/content_hash.h"
#include "common/job_snapshot.h"
#include "farm/embedded_run.h"
#include "farm_fixtures.h"
#include "worker/job_resolve.h"

namespace dofarm::farm_testing {
namespace {

// Content hash of every regular file under `dir` (relative path -> hash),
// state folders excluded: what a user would call "the output".
std::map<std::string, std::string> folder_contents(const fs::path& dir) {
  std::map<std::string, std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string rel = fs::relative(e.path(), dir).string();
    if (rel.rfind(".dofarm-state", 0) == 0) continue;
    if (e.is_regular_file()) out[rel] = hash_regular_file(e.path()).hash;
  }
  return out;
}

// A private copy of the Cornell scene (glTF and its .bin), so a test may
// change it.
fs::path copy_cornell(const fs::path& dir) {
  fs::create_directories(dir);
  const fs::path src = cornell_scene().parent_path();
  fs::copy_file(src / "cornell.gltf", dir / "cornell.gltf");
  fs::copy_file(src / "cornell.bin", dir / "cornell.bin");
  return dir / "cornell.gltf";
}

std::string shard_attr_seed(const fs::path& out) {
  Manifest m = load_manifest(out);
  ShardReader r(out / m.shards.at(0).file);
  return std::to_string(r.info().seed);
}

// `dofarm run SPEC --out OUT` with one one-thread worker, plus `extra`.
CliResult run_job(const fs::path& dir, const std::string& name, const fs::path& spec,
                  const fs::path& out, std::vector<std::string> extra = {}) {
  std::vector<std::string> args = {"run",       spec.string(), "--out",     out.string(),
                                   "--workers", "1",           "--threads", "1"};
  args.insert(args.end(), extra.begin(), extra.end());
  return run_cli(dir, name, args);
}

// The job with frames 0 and 1 (one shard) in `dir`/job.toml.
fs::path two_frame_job(const fs::path& dir) {
  TinyJob j;
  j.frame_end = 1;
  return write_job(dir, "job.toml", j);
}

TEST(JobValue, SecondJobIntoTheSameFolderIsRefusedAndNothingChanges) {
  TempDir dir;
  const fs::path spec = two_frame_job(dir.path());
  const fs::path out = dir / "out";
  CliResult first = run_job(dir.path(), "first", spec, out);
  ASSERT_EQ(first.status, 0) << first.err;
  const auto before = folder_contents(out);

  // Another seed, another frame range: each a different job.
  for (const std::vector<std::string>& sets :
       {std::vector<std::string>{"--set", "seed=8"},
        std::vector<std::string>{"--set", "frames.end=2"}}) {
    CliResult second = run_job(dir.path(), "second", spec, out, sets);
    EXPECT_EQ(second.status, 2) << second.err;
    EXPECT_NE(second.err.find(out.string()), std::string::npos) << second.err;
    EXPECT_NE(second.err.find("holds batch b-"), std::string::npos) << second.err;
    const std::string key = sets[1].substr(0, sets[1].find('='));
    EXPECT_NE(second.err.find(key + ": "), std::string::npos)
        << "the refusal should name the key that differs (" << key << "): " << second.err;
    EXPECT_EQ(folder_contents(out), before) << "a refused run changed the folder";
  }
  // The same job again resumes (nothing to do) and still holds every frame.
  CliResult again = run_job(dir.path(), "again", spec, out);
  EXPECT_EQ(again.status, 0) << again.err;
  EXPECT_TRUE(shards_match_render(out, spec));
}

TEST(JobValue, EditedSpecIsRefusedInsteadOfResumed) {
  TempDir dir;
  const fs::path spec = two_frame_job(dir.path());
  const fs::path out = dir / "out";
  ASSERT_EQ(run_job(dir.path(), "first", spec, out).status, 0);
  // Edit the file itself (not a --set): seed 7 -> 8.
  std::string text = read_text(spec);
  text.replace(text.find("seed = 7"), 8, "seed = 8");
  write_text(spec, text);
  CliResult second = run_job(dir.path(), "second", spec, out);
  EXPECT_EQ(second.status, 2) << second.err;
  EXPECT_NE(second.err.find("seed: 7 -> 8"), std::string::npos) << second.err;
  EXPECT_EQ(shard_attr_seed(out), "7");
}

TEST(JobValue, SubmitOfAnotherJobIntoABusyFolderIsRefused) {
  TempDir dir;
  const fs::path spec = two_frame_job(dir.path());
  const fs::path out = dir / "out";
  CoordinatorProcess coord(dir.path(), "coord", dir / "state", 30);
  const std::vector<std::string> submit = {"submit", spec.string(), "--coordinator",
                                           coord.endpoint(), "--out", out.string()};
  CliResult a = run_cli(dir.path(), "a", submit);
  ASSERT_EQ(a.status, 0) << a.err;
  const std::string batch = a.out.substr(0, a.out.find('\n'));
  // The same job again: the same batch, not a second one.
  CliResult same = run_cli(dir.path(), "same", submit);
  ASSERT_EQ(same.status, 0) << same.err;
  EXPECT_EQ(same.out.substr(0, same.out.find('\n')), batch);
  // Another job into the same folder: refused, named.
  std::vector<std::string> other = submit;
  other.insert(other.end(), {"--set", "seed=9"});
  CliResult b = run_cli(dir.path(), "b", other);
  EXPECT_EQ(b.status, 2) << b.err;
  EXPECT_NE(b.err.find(batch), std::string::npos) << b.err;
  EXPECT_NE(b.err.find("seed: 7 -> 9"), std::string::npos) << b.err;
  Json st = farm_status(coord.endpoint());
  EXPECT_EQ(st.at("batches").size(), 1u) << st.dump(2);
  // The coordinator checks too: a hand-made submit that skips the CLI's check
  // (another job's snapshot, copied into the folder) is refused.
  worker::ResolvedJob r = worker::resolve_job(spec, {"seed=10"});
  worker::materialize_job(r, out);
  protocol::Message reply = call_coordinator(
      {coord.endpoint(), std::nullopt, 10000},
      protocol::encode("submit", {{"snapshot", r.snapshot.to_json(-1)}, {"out_dir", out.string()}}));
  ASSERT_EQ(reply.type, "error");
  EXPECT_NE(reply.str("message").find(batch), std::string::npos) << reply.str("message");
  EXPECT_EQ(farm_status(coord.endpoint()).at("batches").size(), 1u);
}

TEST(JobValue, SpecEditedAfterSubmitChangesNothingInTheBatch) {
  TempDir dir;
  const fs::path spec = two_frame_job(dir.path());
  const fs::path original = dir / "original.toml";
  fs::copy_file(spec, original);
  const fs::path out = dir / "out";
  CoordinatorProcess coord(dir.path(), "coord", dir / "state", 30);
  CliResult a = run_cli(dir.path(), "submit", {"submit", spec.string(), "--coordinator",
                                               coord.endpoint(), "--out", out.string()});
  ASSERT_EQ(a.status, 0) << a.err;
  const std::string batch = a.out.substr(0, a.out.find('\n'));
  // Before any worker starts, the spec changes seed and spp, and the scene
  // file it names is replaced by garbage: the batch must not notice.
  std::string text = read_text(spec);
  text.replace(text.find("seed = 7"), 8, "seed = 8");
  write_text(spec, text);
  Child w = start_worker(dir.path(), coord.endpoint(), "w1");
  ASSERT_TRUE(poll_until("batch done", [&] { return batch_state(coord.endpoint(), batch) == "done"; }));
  EXPECT_TRUE(shards_match_render(out, original));
  EXPECT_EQ(shard_attr_seed(out), "7");
}

TEST(JobValue, WorkerRendersTheSceneOfEachSubmitNotItsCachedOne) {
  TempDir dir;
  TinyJob j;
  j.frame_end = 0;
  j.per_shard = 1;
  j.scene = copy_cornell(dir / "scene");
  const fs::path spec = write_job(dir.path(), "job.toml", j);
  CoordinatorProcess coord(dir.path(), "coord", dir / "state", 30);
  Child w = start_worker(dir.path(), coord.endpoint(), "w1");  // one long-running worker
  auto submit_and_wait = [&](const fs::path& out) {
    CliResult r = run_cli(dir.path(), "submit-" + out.filename().string(),
                          {"submit", spec.string(), "--coordinator", coord.endpoint(), "--out",
                           out.string()});
    EXPECT_EQ(r.status, 0) << r.err;
    const std::string batch = r.out.substr(0, r.out.find('\n'));
    EXPECT_TRUE(poll_until("batch " + batch + " done",
                           [&] { return batch_state(coord.endpoint(), batch) == "done"; }));
  };
  submit_and_wait(dir / "out1");
  // Overwrite the scene file in place: the back wall turns another colour.
  std::string gltf = read_text(j.scene);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(gltf, m, std::regex(R"("baseColorFactor"\s*:\s*\[[^\]]*\])")));
  gltf.replace(m.position(0), m.length(0), R"("baseColorFactor": [0.1, 0.9, 0.2, 1.0])");
  write_text(j.scene, gltf);
  submit_and_wait(dir / "out2");
  EXPECT_TRUE(shards_match_render(dir / "out2", spec)) << "the worker rendered a stale scene";
  ShardReader a(dir / "out1" / load_manifest(dir / "out1").shards.at(0).file);
  ShardReader b(dir / "out2" / load_manifest(dir / "out2").shards.at(0).file);
  EXPECT_NE(a.info().scene_hash, b.info().scene_hash);
  EXPECT_NE(a.info().job_hash, b.info().job_hash);
  EXPECT_TRUE(is_content_hash(b.info().job_hash));
}

TEST(JobValue, SnapshotCoversEveryFileTheSceneReads) {
  TempDir dir;
  const fs::path scene = copy_cornell(dir / "scene");
  TinyJob j;
  j.scene = scene;
  const fs::path spec = write_job(dir.path(), "job.toml", j);
  worker::ResolvedJob a = worker::resolve_job(spec, {});
  std::vector<std::string> paths;
  for (const JobInput& in : a.snapshot.inputs) paths.push_back(in.path);
  EXPECT_EQ(paths, (std::vector<std::string>{"files/cornell.bin", "files/cornell.gltf"}));
  // One changed byte in the buffer (a low mantissa bit of the first float)
  // makes another job with another scene hash.
  std::string bin = read_text(dir / "scene/cornell.bin");
  bin[0] = char(bin[0] ^ 1);
  write_text(dir / "scene/cornell.bin", bin);
  worker::ResolvedJob b = worker::resolve_job(spec, {});
  EXPECT_NE(a.snapshot.hash(), b.snapshot.hash());
  EXPECT_EQ(a.snapshot.spec_toml, b.snapshot.spec_toml);
  // The same content elsewhere, under another file name of the spec, is
  // the same job.
  const fs::path spec2 = dir / "renamed.toml";
  fs::copy_file(spec, spec2);
  EXPECT_EQ(worker::resolve_job(spec2, {}).snapshot.hash(), b.snapshot.hash());
  // The canonical spec reads back to the same job (every key, floats exact).
  const fs::path out = dir / "out";
  fs::create_directories(out);
  worker::materialize_job(b, out);
  LoadedJob loaded = load_job(out, b.snapshot.hash());
  EXPECT_EQ(canonical_spec_toml(loaded.spec, "files/cornell.gltf", ""), b.snapshot.spec_toml);
  // A copy tampered with after submit is caught before use.
  write_text(job_dir(out, b.snapshot.hash()) / "files/cornell.bin", bin + "x");
  EXPECT_THROW(load_job(out, b.snapshot.hash()), RuntimeError);
}

// The embedded farm as a module (what `dofarm run` calls): a run, its
// resume, and a refusal, in process.
TEST(EmbeddedRun, RunsResumesAndRefusesAnotherJobInProcess) {
  TempDir dir;
  TinyJob j;
  j.frame_end = 1;
  farm::EmbeddedRunOptions o;
  o.spec = write_job(dir.path(), "job.toml", j);
  o.out = dir / "out";
  o.workers = 1;
  o.threads = 1;
  o.exe = dofarm_exe();
  o.progress = false;
  std::atomic<bool> stop{false};
  farm::EmbeddedRunResult first = farm::run_embedded(o, stop);
  EXPECT_FALSE(first.resumed);
  EXPECT_EQ(first.status.batch.state, coordinator::BatchState::kDone);
  EXPECT_EQ(first.status.frames_packed, 2);
  EXPECT_EQ(read_output_owner(o.out)->batch, first.batch);
  farm::EmbeddedRunResult again = farm::run_embedded(o, stop);
  EXPECT_TRUE(again.resumed);
  EXPECT_EQ(again.batch, first.batch);
  EXPECT_EQ(again.job, first.job);
  o.overrides = {"image.width=48"};
  try {
    farm::run_embedded(o, stop);
    ADD_FAILURE() << "another job ran into the folder";
  } catch (const farm::RunRefused& e) {
    EXPECT_NE(std::string(e.what()).find("image.width: 32 -> 48"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(shards_match_render(o.out, o.spec));
}

// The size a from-scene spec leaves out follows the glTF camera (courtyard:
// aspectRatio 16:9) and is written into the canonical spec, so the job hash,
// the planner and the workers all see it; a derived side beyond the limit is
// an error at the key that was given.
TEST(JobValue, SceneCameraSizeIsResolvedIntoTheCanonicalSpec) {
  TempDir dir;
  const fs::path courtyard = fs::path(DOFARM_SOURCE_DIR) / "jobs/scenes/courtyard.gltf";
  auto spec_with = [&](const std::string& name, const std::string& image) {
    const fs::path p = dir / name;
    write_text(p, "scene = \"" + courtyard.string() + "\"\n" + image +
                      "[camera]\nfrom_scene = true\n");
    return p;
  };
  struct Case {
    std::string image;
    int width, height;
  };
  for (const Case& c : {Case{"", 512, 288}, Case{"[image]\nwidth = 1920\n", 1920, 1080},
                        Case{"[image]\nheight = 90\n", 160, 90},
                        Case{"[image]\nwidth = 64\nheight = 64\n", 64, 64}}) {
    SCOPED_TRACE(c.image);
    worker::ResolvedJob job = worker::resolve_job(spec_with("job.toml", c.image), {});
    EXPECT_EQ(job.spec.width, c.width);
    EXPECT_EQ(job.spec.height, c.height);
    const std::string size = "[image]\nwidth = " + std::to_string(c.width) +
                             "\nheight = " + std::to_string(c.height) + "\n";
    EXPECT_NE(job.snapshot.spec_toml.find(size), std::string::npos) << job.snapshot.spec_toml;
  }
  // The default and the explicit 16:9 size are the same job.
  EXPECT_EQ(worker::resolve_job(spec_with("a.toml", ""), {}).snapshot.hash(),
            worker::resolve_job(spec_with("b.toml", "[image]\nwidth = 512\nheight = 288\n"), {})
                .snapshot.hash());
  try {
    worker::resolve_job(spec_with("tall.toml", "[image]\nheight = 16384\n"), {});
    ADD_FAILURE() << "a 29127-pixel width was accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "image.height");
    EXPECT_EQ(e.loc().line, 3) << e.what();
  }
}

// camera.name picks one of the file's cameras (by its node's name) and is
// part of the job; a name the file lacks is an error at the key that lists
// the cameras; a file with several cameras and no name says which it takes.
TEST(JobValue, CameraNameChoosesTheSceneCameraAndTheFirstIsSaidToBeTaken) {
  TempDir dir;
  const fs::path scenes = fs::path(DOFARM_SOURCE_DIR) / "jobs/scenes";
  fs::copy_file(scenes / "cornell.bin", dir / "cornell.bin");
  Json doc = Json::parse(read_text(scenes / "cornell.gltf"));
  for (const char* name : {"Wide", "Closeup"}) {
    doc["nodes"].push_back({{"name", name},
                            {"camera", doc.value("cameras", Json::array()).size()},
                            {"translation", {0.0, 1.0, std::string(name) == "Wide" ? 5.0 : 2.0}}});
    doc["cameras"].push_back(
        {{"type", "perspective"}, {"perspective", {{"yfov", 0.6}, {"aspectRatio", 1.0}}}});
    doc["scenes"][0]["nodes"].push_back(doc["nodes"].size() - 1);
  }
  write_text(dir / "two.gltf", doc.dump());
  auto spec_with = [&](const std::string& name, const std::string& camera) {
    const fs::path p = dir / name;
    write_text(p,
               "scene = \"two.gltf\"\n[image]\nwidth = 32\nheight = 32\n[camera]\n"
               "from_scene = true\n" +
                   camera);
    return p;
  };
  CliResult first = run_cli(dir.path(), "first",
                            {"render", spec_with("first.toml", "").string(), "--frame", "0",
                             "--set", "buffers.versions=1", "--set", "buffers.reference_spp=1",
                             "--out", (dir / "first.exr").string()});
  EXPECT_EQ(first.status, 0) << first.err;
  EXPECT_NE(first.err.find("the scene has 2 cameras"), std::string::npos) << first.err;
  EXPECT_NE(first.err.find("as camera.name is not set"), std::string::npos) << first.err;

  worker::ResolvedJob closeup =
      worker::resolve_job(spec_with("closeup.toml", "name = \"Closeup\"\n"), {});
  EXPECT_EQ(closeup.spec.camera_name, "Closeup");
  EXPECT_NE(closeup.snapshot.spec_toml.find("name = \"Closeup\""), std::string::npos);
  worker::ResolvedJob wide = worker::resolve_job(spec_with("wide.toml", "name = \"Wide\"\n"), {});
  EXPECT_NE(wide.snapshot.hash(), closeup.snapshot.hash());
  try {
    worker::resolve_job(spec_with("side.toml", "name = \"Side\"\n"), {});
    ADD_FAILURE() << "a camera the scene lacks was accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "camera.name");
    EXPECT_EQ(e.loc().line, 7) << e.what();
    EXPECT_NE(std::string(e.what()).find("has no camera \"Side\"; its cameras: "),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("\"Closeup\""), std::string::npos) << e.what();
  }
  CliResult named = run_cli(dir.path(), "named",
                            {"render", spec_with("named.toml", "name = \"Wide\"\n").string(),
                             "--frame", "0", "--set", "buffers.versions=1", "--set",
                             "buffers.reference_spp=1", "--out", (dir / "named.exr").string()});
  EXPECT_EQ(named.status, 0) << named.err;
  EXPECT_EQ(named.err.find("cameras ("), std::string::npos) << named.err;
}

// Defect 12: content errors are found before anything exists.
TEST(JobValue, ContentErrorsAreBadInputAndWriteNothing) {
  TempDir dir;
  write_text(dir / "not_gltf.gltf", "this is not a glTF file\n");
  write_text(dir / "empty.gltf", R"({"asset": {"version": "2.0"}})");
  write_text(dir / "not_image.exr", "not an image\n");
  TinyJob bad_scene;
  bad_scene.scene = dir / "not_gltf.gltf";
  TinyJob empty_scene;
  empty_scene.scene = dir / "empty.gltf";
  const fs::path env_job = write_job(dir.path(), "env.toml", TinyJob{});
  write_text(env_job, read_text(env_job) + "\n[environment]\nmap = \"not_image.exr\"\n");
  struct Case {
    fs::path spec;
    std::string where;  // file:line:column and key
  };
  const fs::path bad_spec = write_job(dir.path(), "bad_scene.toml", bad_scene);
  const fs::path empty_spec = write_job(dir.path(), "empty_scene.toml", empty_scene);
  const std::string env_text = read_text(env_job);  // the map is on its last line
  const int env_line = int(std::count(env_text.begin(), env_text.end(), '\n'));
  // camera.from_scene on a scene without a camera (it used to render from
  // the origin), and autofocus looking out of the open box at nothing.
  const fs::path no_camera = dir / "no_camera.toml";
  write_text(no_camera, "scene = \"" + cornell_scene().string() +
                            "\"\nseed = 7\n\n[camera]\nfrom_scene = true\n");
  const fs::path nothing_to_focus = dir / "nothing_to_focus.toml";
  write_text(nothing_to_focus, "scene = \"" + cornell_scene().string() +
                                   "\"\n[image]\nwidth = 16\nheight = 16\n[[camera.key]]\n"
                                   "position = [0.0, 1.0, 3.9]\nlook_at = [0.0, 1.0, 10.0]\n"
                                   "aperture = 0.05\nfocus = \"auto\"\n");
  // camera.from_scene on a scene whose camera is orthographic with a ymag
  // of 0, which glTF forbids (it would show a line of the scene).
  write_text(dir / "ortho.gltf",
             R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
    "nodes": [{"mesh": 0}, {"name": "Plan", "camera": 0, "translation": [0.5, 5, 0.5],
               "rotation": [-0.7071068, 0, 0, 0.7071068]}],
    "cameras": [{"type": "orthographic",
                 "orthographic": {"xmag": 1, "ymag": 0, "znear": 0.1, "zfar": 10}}],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
    "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                   "min": [0, 0, 0], "max": [1, 0, 1]},
                  {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    "bufferViews": [{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48,
                     "byteLength": 12}],
    "buffers": [{"byteLength": 60, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAAAAAAAAAAAAAIA/AACAPwAAAAAAAIA/AACAPwAAAAAAAAAAAAABAAIAAAACAAMA"}]})");
  const fs::path ortho = dir / "ortho.toml";
  write_text(ortho,
             "scene = \"ortho.gltf\"\n[image]\nwidth = 16\nheight = 16\n\n[camera]\n"
             "from_scene = true\n[environment]\ncolor = [1.0, 1.0, 1.0]\n");
  // A lamp sized by a name the scene does not have (its lamps: Point, Spot,
  // Sun).
  const fs::path no_such_lamp = dir / "no_such_lamp.toml";
  write_text(no_such_lamp,
             "scene = \"" +
                 (fs::path(DOFARM_TEST_DATA) / "blender" / "lamps_and_texture.glb").string() +
                 "\"\n[image]\nwidth = 16\nheight = 16\n[[camera.key]]\n"
                 "position = [0.0, 3.0, 0.01]\nlook_at = [0.0, 0.0, 0.0]\n"
                 "[[lights.lamp]]\nname = \"Key\"\nradius = 0.1\n");
  const std::vector<Case> cases = {
      {no_camera, no_camera.string() + ":5:14: \"camera.from_scene\": the scene"},
      {no_such_lamp, no_such_lamp.string() + ":9:8: \"lights.lamp.0.name\": the scene"},
      {ortho, ortho.string() + ":7:14: \"camera.from_scene\": the scene \"" +
                  (dir / "ortho.gltf").string() +
                  "\" has no camera that dofarm can render: its camera \"Plan\" is orthographic"},
      {nothing_to_focus, nothing_to_focus.string() + ":9:9: \"camera.key.0.focus\": autofocus"},
      {bad_spec, bad_spec.string() + ":1:1: \"scene\""},
      {empty_spec, empty_spec.string() + ":1:1: \"scene\""},
      {env_job, env_job.string() + ":" + std::to_string(env_line) + ":1: \"environment.map\""}};
  CoordinatorProcess coord(dir.path(), "coord", dir / "state", 30);
  for (const Case& c : cases) {
    SCOPED_TRACE(c.spec.string());
    const fs::path out = dir / ("out_" + c.spec.stem().string());
    for (const std::vector<std::string>& args :
         {std::vector<std::string>{"run", c.spec.string(), "--out", out.string()},
          std::vector<std::string>{"submit", c.spec.string(), "--coordinator", coord.endpoint(),
                                   "--out", out.string()},
          std::vector<std::string>{"render", c.spec.string(), "--frame", "0", "--out",
                                   (out / "frame.exr").string()}}) {
      CliResult r = run_cli(dir.path(), "cli", args);
      EXPECT_EQ(r.status, 2) << args[0] << ": " << r.err;
      EXPECT_NE(r.err.find(c.where), std::string::npos) << args[0] << ": " << r.err;
      EXPECT_FALSE(fs::exists(out)) << args[0] << " created " << out;
    }
  }
  EXPECT_EQ(farm_status(coord.endpoint()).at("batches").size(), 0u);
}

}  // namespace
}  // namespace dofarm::farm_testing

namespace dofarm::farm_testing {
namespace {

// Defect 6, the submit half: a spec "file" that is a FIFO or a device is
// refused at once (it used to stall the coordinator for seconds and grow it
// by gigabytes); the coordinator itself never opens a path a client names
// unless it is a regular file of bounded size, so a FIFO planted as a job's
// snapshot is refused without blocking.
TEST(JobValue, FifoAndDeviceSpecsAreRefusedAtOnce) {
  TempDir dir;
  const fs::path fifo = dir / "spec.fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  CoordinatorProcess coord(dir.path(), "coord", dir / "state", 30);
  for (const fs::path& spec : {fifo, fs::path("/dev/zero")}) {
    for (const std::vector<std::string>& args :
         {std::vector<std::string>{"run", spec.string(), "--out", (dir / "out").string()},
          std::vector<std::string>{"submit", spec.string(), "--coordinator", coord.endpoint(),
                                   "--out", (dir / "out").string()}}) {
      const auto t0 = Clock::now();
      CliResult r = run_cli(dir.path(), "cli", args, 20);
      EXPECT_EQ(r.status, 2) << args[0] << " " << spec << ": " << r.err;
      EXPECT_NE(r.err.find("not a regular file"), std::string::npos) << r.err;
      EXPECT_LT(seconds_since(t0), 10) << args[0] << " " << spec << " took too long";
      EXPECT_FALSE(fs::exists(dir / "out"));
    }
  }
  // A job folder whose job.json is a FIFO: the coordinator answers at once.
  worker::ResolvedJob job = worker::resolve_job(two_frame_job(dir.path()), {});
  const fs::path planted = job_dir(dir / "out", job.snapshot.hash());
  fs::create_directories(planted);
  ASSERT_EQ(::mkfifo((planted / "job.json").c_str(), 0644), 0);
  const auto t0 = Clock::now();
  protocol::Message reply = call_coordinator(
      {coord.endpoint(), std::nullopt, 10000},
      protocol::encode("submit", {{"snapshot", job.snapshot.to_json(-1)},
                                  {"out_dir", (dir / "out").string()}}));
  EXPECT_EQ(reply.type, "error");
  EXPECT_NE(reply.str("message").find("not a regular file"), std::string::npos)
      << reply.str("message");
  EXPECT_LT(seconds_since(t0), 5);
  EXPECT_EQ(farm_status(coord.endpoint()).at("batches").size(), 0u);
}

}  // namespace
}  // namespace dofarm::farm_testing
