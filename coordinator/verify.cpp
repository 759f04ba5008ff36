#include "coordinator/verify.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <map>
#include <set>

#include "common/checksum.h"
#include "common/error.h"
#include "common/job_snapshot.h"
#include "common/manifest.h"
#include "common/shard.h"
#include "coordinator/job_store.h"
#include "coordinator/planner.h"
#include "coordinator/scheduler.h"

namespace dofarm::coordinator {

namespace fs = std::filesystem;
using nlohmann::json;

std::string check_output_file(const fs::path& path, uint64_t checksum, std::optional<uint64_t> size,
                              uint64_t* actual_size) {
  // O_NOFOLLOW: a symlink is refused, not followed out of the folder;
  // O_NONBLOCK: a FIFO does not stall the open (and is refused below).
  const int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return "missing";
    if (errno == ELOOP) return "a symlink, not a regular file";
    return std::string("cannot open: ") + std::strerror(errno);
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    return "not a regular file";
  }
  const uint64_t found = uint64_t(st.st_size);
  if (actual_size) *actual_size = found;
  if (size && found != *size) {
    ::close(fd);
    return "size " + std::to_string(found) + ", expected " + std::to_string(*size);
  }
  // Read from the descriptor that was checked, not the name again.
  Checksum64 sum;
  std::vector<char> buffer(1 << 20);
  for (;;) {
    const ssize_t n = ::read(fd, buffer.data(), buffer.size());
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int err = errno;
      ::close(fd);
      return std::string("read failed: ") + std::strerror(err);
    }
    if (n == 0) break;
    sum.update(buffer.data(), size_t(n));
  }
  ::close(fd);
  if (sum.digest() != checksum)
    return "checksum " + checksum_to_string(sum.digest()) + ", expected " +
           checksum_to_string(checksum);
  return "";
}

ResumeCheck verify_batch_outputs(Scheduler& scheduler, const std::string& batch_id) {
  ResumeCheck r;
  auto staged_problem = [](const StagedTile& t) {
    const std::optional<uint64_t> sum = parse_checksum(t.checksum);
    return sum ? check_output_file(t.staged_path, *sum) : std::string("no checksum recorded");
  };
  for (const StagedTile& t : scheduler.staged_tiles_to_verify(batch_id)) {
    const std::string why = staged_problem(t);
    if (why.empty()) continue;
    spdlog::warn("staged tile {} ({}): rendering it again", t.staged_path, why);
    scheduler.invalidate(t.task_id);
    ++r.tiles_requeued;
  }

  const std::vector<PackedShard> packed = scheduler.packed_shards(batch_id);
  if (packed.empty()) return r;
  const fs::path out = packed.front().out_dir;
  std::optional<Manifest> manifest;
  try {
    manifest = load_manifest(out);
    std::error_code ec;
    if (!fs::exists(out / kManifestFile, ec)) manifest.reset();  // absent: rebuilt below
  } catch (const std::exception& e) {
    spdlog::warn("{}; rebuilding it from the shards that verify", e.what());
  }
  std::vector<ManifestEntry> relist;  // sound shards the manifest lacks or misstates
  std::vector<const PackedShard*> bad;
  for (const PackedShard& p : packed) {
    const std::optional<uint64_t> sum = parse_checksum(p.checksum);
    uint64_t size = 0;
    std::string why = sum ? check_output_file(out / p.range.file, *sum, std::nullopt, &size)
                          : "no checksum recorded at pack time";
    const ManifestEntry* listed = nullptr;
    if (manifest)
      for (const ManifestEntry& e : manifest->shards)
        if (e.file == p.range.file) listed = &e;
    if (why.empty() &&
        !(listed && listed->checksum == *sum && listed->size == size &&
          listed->frame_start == p.range.frame_start && listed->frame_end == p.range.frame_end)) {
      try {
        ShardReader reader(out / p.range.file);
        ManifestEntry e;
        e.file = p.range.file;
        e.batch_id = reader.info().batch_id;
        e.scene_id = reader.info().scene_id;
        e.frame_start = p.range.frame_start;
        e.frame_end = p.range.frame_end;
        e.size = size;
        e.checksum = *sum;
        if (reader.info().frame_start != e.frame_start || reader.info().frame_end != e.frame_end)
          why = "holds frames " + std::to_string(reader.info().frame_start) + ".." +
                std::to_string(reader.info().frame_end);
        else
          relist.push_back(e);
      } catch (const std::exception& e) {
        why = e.what();
      }
    }
    if (!why.empty()) {
      spdlog::warn("shard {} ({}): packing it again", (out / p.range.file).string(), why);
      bad.push_back(&p);
    }
  }
  if (!relist.empty() || !bad.empty() || !manifest) {
    rewrite_manifest(out, [&](Manifest& m, bool readable) {
      r.manifest_rebuilt = !readable || !manifest;
      // A listed shard is complete (manifest.h): a damaged one leaves the list.
      std::erase_if(m.shards, [&](const ManifestEntry& e) {
        for (const PackedShard* p : bad)
          if (p->range.file == e.file) return true;
        for (const ManifestEntry& n : relist)
          if (n.file == e.file) return true;
        return false;
      });
      m.shards.insert(m.shards.end(), relist.begin(), relist.end());
    });
  }
  for (const PackedShard* p : bad) {
    scheduler.invalidate(p->task_id);
    // Packing removed the staged tiles; those still sound are packed again
    // as they are, the others rendered again.
    for (const StagedTile& t : p->inputs) {
      if (staged_problem(t).empty()) continue;
      scheduler.invalidate(t.task_id);
    }
    ++r.shards_redone;
  }
  return r;
}

bool FolderReport::ok() const {
  if (!problems.empty() || !unlisted.empty()) return false;
  for (const ShardVerdict& s : shards)
    if (!s.problem.empty()) return false;
  for (const StagedVerdict& s : staged)
    if (!s.problem.empty()) return false;
  return true;
}

namespace {

bool looks_like_shard(const std::string& name) {
  return name.size() > 3 && (name.compare(name.size() - 3, 3, ".h5") == 0 ||
                             name.find(".h5.tmp-") != std::string::npos);
}

// The batch the folder's ownership record (OUT/.dofarm-owner.json) names,
// if it names one.
std::string owner_batch(const fs::path& dir, std::vector<std::string>& problems) {
  try {
    if (std::optional<OutputOwner> o = read_output_owner(dir)) return o->batch;
  } catch (const std::exception& e) {
    problems.push_back(e.what());
  }
  return "";
}

std::string same_dir(const fs::path& a) {
  std::error_code ec;
  fs::path c = fs::weakly_canonical(a, ec);
  return (ec ? a : c).lexically_normal().string();
}

// Checks the done pack tasks (and the tiles of unpacked shards) of `batch`.
void verify_against_store(FolderReport& r, JobStore& store, const BatchRow& batch,
                          const std::optional<Manifest>& manifest, std::set<std::string>& listed,
                          std::set<std::string>& staged_known) {
  const std::vector<TaskRow> tasks = store.tasks(batch.id);
  std::map<int, ShardRange> ranges;
  for (const ShardRange& s : shard_ranges(batch.frame_start, batch.frame_end, batch.per_shard))
    ranges[s.index] = s;
  std::set<int> packed;
  for (const TaskRow& t : tasks) {
    if (t.kind != TaskKind::kPackShard) continue;
    const ShardRange& range = ranges.at(t.shard);
    ShardVerdict v{range.file, range.frame_start, range.frame_end, ""};
    listed.insert(range.file);
    if (t.state != TaskState::kDone) {
      v.problem = std::string("not packed (") + to_string(t.state) +
                  (t.last_error.empty() ? "" : ": " + t.last_error) + ")";
      r.shards.push_back(v);
      continue;
    }
    packed.insert(t.shard);
    const std::optional<uint64_t> recorded = parse_checksum(t.checksum);
    if (!recorded) {
      v.problem = "the job store holds no checksum for it";
      r.shards.push_back(v);
      continue;
    }
    uint64_t size = 0;
    v.problem = check_output_file(r.dir / range.file, *recorded, std::nullopt, &size);
    if (v.problem.empty() && manifest) {
      auto e = std::find_if(manifest->shards.begin(), manifest->shards.end(),
                            [&](const ManifestEntry& m) { return m.file == range.file; });
      if (e == manifest->shards.end())
        v.problem = "not listed in manifest.json";
      else if (e->checksum != *recorded || e->size != size)
        v.problem = "manifest.json says size " + std::to_string(e->size) + ", " +
                    checksum_to_string(e->checksum) + "; the file has " + std::to_string(size) +
                    ", " + checksum_to_string(*recorded);
    }
    r.shards.push_back(v);
  }
  // Done tiles of unpacked shards: their staged files wait for the pack.
  for (const TaskRow& t : tasks) {
    if (t.kind != TaskKind::kRenderTile || t.state != TaskState::kDone || packed.count(t.shard))
      continue;
    const fs::path p = t.staged_path;
    std::error_code ec;
    const std::string rel = p.lexically_relative(r.dir).string();
    staged_known.insert(rel);
    const std::optional<uint64_t> sum = parse_checksum(t.checksum);
    StagedVerdict v{rel, "awaiting pack", ""};
    v.problem = sum ? check_output_file(p, *sum) : "the job store holds no checksum for it";
    r.staged.push_back(v);
  }
}

}  // namespace

FolderReport verify_folder(const fs::path& dir_in, const VerifyOptions& options) {
  std::error_code ec;
  if (!fs::is_directory(dir_in, ec)) throw RuntimeError(dir_in.string() + ": not a folder");
  FolderReport r;
  r.dir = fs::absolute(dir_in).lexically_normal();
  if (r.dir.has_filename() == false) r.dir = r.dir.parent_path();

  std::optional<Manifest> manifest;
  try {
    manifest = load_manifest(r.dir);
    if (!fs::exists(r.dir / kManifestFile, ec)) r.problems.push_back("manifest.json: missing");
  } catch (const std::exception& e) {
    r.problems.push_back(e.what());
  }

  const fs::path state = options.state_dir.empty() ? r.dir / ".dofarm-state" : options.state_dir;
  std::set<std::string> listed, staged_known;
  bool from_store = false;
  if (fs::exists(state / "dofarm.sqlite", ec)) {
    JobStore store(state / "dofarm.sqlite");
    std::optional<BatchRow> batch;
    std::string wanted =
        options.batch_id.empty() ? owner_batch(r.dir, r.problems) : options.batch_id;
    if (!wanted.empty()) {
      batch = store.batch(wanted);
      if (!batch) r.problems.push_back("the job store has no batch " + wanted);
    } else {
      for (const BatchRow& b : store.batches())  // oldest first: the newest wins
        if (same_dir(b.out_dir) == same_dir(r.dir)) batch = b;
    }
    if (batch) {
      from_store = true;
      r.batch_id = batch->id;
      r.batch_state = to_string(batch->state);
      r.record = "job store " + (state / "dofarm.sqlite").string() + ", batch " + batch->id;
      verify_against_store(r, store, *batch, manifest, listed, staged_known);
      // A manifest entry the batch does not have is another job's, or made up.
      if (manifest)
        for (const ManifestEntry& e : manifest->shards)
          if (!listed.count(e.file))
            r.shards.push_back({e.file, e.frame_start, e.frame_end,
                                "listed in manifest.json but not a shard of batch " + batch->id});
    }
  }
  if (!from_store) {
    r.record = "manifest.json (no job store for this folder)";
    if (manifest)
      for (const ManifestEntry& e : manifest->shards) {
        listed.insert(e.file);
        r.shards.push_back({e.file, e.frame_start, e.frame_end,
                            check_output_file(r.dir / e.file, e.checksum, e.size)});
      }
  }
  std::sort(r.shards.begin(), r.shards.end(),
            [](const ShardVerdict& a, const ShardVerdict& b) { return a.file < b.file; });

  for (const fs::directory_entry& e : fs::directory_iterator(r.dir, ec)) {
    const std::string name = e.path().filename().string();
    if (looks_like_shard(name) && !listed.count(name)) r.unlisted.push_back(name);
  }
  std::sort(r.unlisted.begin(), r.unlisted.end());

  if (fs::is_directory(r.dir / ".staging", ec)) {
    for (const fs::directory_entry& e : fs::recursive_directory_iterator(r.dir / ".staging", ec)) {
      if (e.is_directory(ec)) continue;
      const std::string rel = e.path().lexically_relative(r.dir).string();
      if (staged_known.count(rel)) continue;
      // No done tile claims it: a tile rendered again elsewhere, or a batch's
      // leftovers. Harmless, but worth knowing about.
      r.staged.push_back({rel, from_store ? "left over (no done task claims it)" : "staged", ""});
    }
  }
  std::sort(r.staged.begin(), r.staged.end(),
            [](const StagedVerdict& a, const StagedVerdict& b) { return a.file < b.file; });
  return r;
}

json folder_report_json(const FolderReport& r) {
  json shards = json::array();
  for (const ShardVerdict& s : r.shards)
    shards.push_back({{"file", s.file},
                      {"frame_start", s.frame_start},
                      {"frame_end", s.frame_end},
                      {"ok", s.problem.empty()},
                      {"problem", s.problem}});
  json staged = json::array();
  for (const StagedVerdict& s : r.staged)
    staged.push_back({{"file", s.file},
                      {"status", s.status},
                      {"ok", s.problem.empty()},
                      {"problem", s.problem}});
  return {{"dir", r.dir.string()},        {"record", r.record}, {"batch", r.batch_id},
          {"batch_state", r.batch_state}, {"ok", r.ok()},       {"shards", shards},
          {"unlisted", r.unlisted},       {"staged", staged},   {"problems", r.problems}};
}

void print_folder_report(const FolderReport& r, std::ostream& out) {
  out << r.dir.string() << ": checked against " << r.record
      << (r.batch_state.empty() ? "" : " (" + r.batch_state + ")") << "\n";
  for (const std::string& p : r.problems) out << "PROBLEM  " << p << "\n";
  int good = 0;
  for (const ShardVerdict& s : r.shards) {
    good += s.problem.empty();
    out << s.file << "  frames " << s.frame_start << ".." << s.frame_end << "  "
        << (s.problem.empty() ? "OK" : s.problem) << "\n";
  }
  for (const std::string& u : r.unlisted) out << u << "  UNLISTED: no record lists it\n";
  int waiting = 0, leftover = 0, bad = 0;
  for (const StagedVerdict& s : r.staged) {
    if (!s.problem.empty()) {
      ++bad;
      out << s.file << "  staged tile, " << s.status << ": " << s.problem << "\n";
    } else if (s.status == "awaiting pack") {
      ++waiting;
    } else {
      ++leftover;
    }
  }
  out << good << "/" << r.shards.size() << " shards OK";
  if (!r.unlisted.empty()) out << ", " << r.unlisted.size() << " unlisted";
  if (!r.staged.empty())
    out << "; staged tiles: " << waiting << " awaiting pack, " << bad << " damaged, " << leftover
        << " left over";
  out << (r.ok() ? "\n" : "\nNOT OK\n");
}

}  // namespace dofarm::coordinator
