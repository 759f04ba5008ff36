#include "trainer/dataset.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>

#include "common/checksum.h"
#include "common/error.h"
#include "common/manifest.h"

namespace dofarm::trainer {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// SplitMix64: turns (seed, index) into independent RNG seeds.
uint64_t mix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

uint64_t hash_name(const std::string& s) {  // FNV-1a, stable across platforms
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : s) h = (h ^ c) * 1099511628211ull;
  return mix(h);
}

// A uniform number in [0, 1) drawn from a shard's content key, the same on
// every machine: what decides its split.
double content_draw(const std::string& key) {
  return double(hash_name(key) >> 11) / double(uint64_t(1) << 53);
}

// A shard failed while being read (damaged chunk, vanished file): the shard
// is dropped and the sample drawn again from the others.
struct ShardReadFailure : RuntimeError {
  ShardReadFailure(std::string f, const std::string& what)
      : RuntimeError(what), file(std::move(f)) {}
  std::string file;
};

constexpr uint64_t kValidationStream = 0x76616c6964ull;  // separates val seeds from train

}  // namespace

ShardSplit assign_split(const std::string& file, const std::string& key, int frames,
                        const DataConfig& data) {
  ShardSplit s;
  s.file = file;
  s.key = key;
  s.frames = frames;
  s.train_end = frames;
  if (data.val_fraction <= 0) return s;
  const double u = content_draw(key);
  if (data.split == SplitMode::kShard) {
    if (u < data.val_fraction) {
      s.train_end = 0;
      s.val_end = frames;
    }
    return s;
  }
  // By whole sequences at the end of the shard, so a validation sequence
  // never shares a frame with a training one; stochastic rounding keeps the
  // expected share exactly val_fraction even for shards of one or two
  // sequences.
  const int sequences = frames / data.sequence;
  const double want = sequences * double(data.val_fraction);
  const int n = std::min(sequences, int(std::floor(want)) + (u < want - std::floor(want) ? 1 : 0));
  if (n == 0) return s;
  s.train_end = frames - n * data.sequence;
  s.val_begin = s.train_end;
  s.val_end = frames;
  return s;
}

std::string shard_content_key(const ShardInfo& info) {
  return checksum_to_string(info.data_checksum);
}

std::vector<ShardSplit> load_split_file(const fs::path& run_dir) {
  std::vector<ShardSplit> out;
  std::ifstream in(run_dir / "split.json");
  if (!in) return out;
  try {
    json j = json::parse(in);
    const bool keyed = j.value("version", 1) >= 2;
    for (const auto& [name, v] : j.at("shards").items()) {
      ShardSplit s;
      s.key = keyed ? name : "";
      s.file = keyed ? v.at("file").get<std::string>() : name;
      s.frames = v.at("frames");
      s.train_begin = v.at("train")[0];
      s.train_end = v.at("train")[1];
      s.val_begin = v.at("val")[0];
      s.val_end = v.at("val")[1];
      out.push_back(s);
    }
  } catch (const json::exception& e) {
    throw RuntimeError((run_dir / "split.json").string() + ": malformed: " + e.what());
  }
  return out;
}

std::vector<std::string> list_shards(const fs::path& dir) {
  std::vector<std::string> out;
  if (fs::exists(dir / kManifestFile)) {
    for (const ManifestEntry& e : load_manifest(dir).shards) out.push_back(e.file);
  } else {
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
      // Only finished names: writers use "<final>.tmp-<pid>" until the rename.
      if (entry.is_regular_file() && entry.path().extension() == ".h5")
        out.push_back(entry.path().filename().string());
    }
    if (ec) throw RuntimeError(dir.string() + ": cannot list the data folder: " + ec.message());
  }
  std::sort(out.begin(), out.end());
  return out;
}

SequenceStream::SequenceStream(fs::path data_dir, fs::path run_dir, DataConfig data,
                               ModelConfig model, uint64_t seed, uint64_t first_index,
                               ShardReaderOptions reader_options)
    : data_dir_(std::move(data_dir)),
      run_dir_(std::move(run_dir)),
      data_(data),
      reader_options_(reader_options),
      model_(std::move(model)),
      seed_(seed),
      next_(first_index),
      claimed_(first_index) {
  if (!fs::is_directory(data_dir_)) throw RuntimeError(data_dir_.string() + ": no such folder");
  for (ShardSplit& sp : load_split_file(run_dir_)) {
    if (sp.key.empty()) {
      legacy_splits_[sp.file] = sp;
    } else {
      known_splits_[sp.key] = sp;
    }
  }
  const bool fresh_split = known_splits_.empty() && legacy_splits_.empty();
  rescan();
  if (fresh_split && data_.val_fraction > 0 && data_.split == SplitMode::kFrames)
    ensure_one_validation_sequence();
  {
    // What the split came to: whole sequences on each side.
    int train_seq = 0, val_seq = 0;
    for (const auto& sh : shards_) {
      train_seq += (sh->split.train_end - sh->split.train_begin) / data_.sequence;
      val_seq += (sh->split.val_end - sh->split.val_begin) / data_.sequence;
    }
    spdlog::info("split: {} of {} whole {}-frame sequences are validation ({:.1f}%; "
                 "data.val_fraction {})",
                 val_seq, train_seq + val_seq, data_.sequence,
                 train_seq + val_seq ? 100.0 * val_seq / (train_seq + val_seq) : 0.0,
                 data_.val_fraction);
  }
  bool any = false;
  for (const auto& s : shards_) any |= s->split.train_end - s->split.train_begin >= data_.sequence;
  if (!any) {
    std::string why = data_dir_.string() + ": no shard holds a " + std::to_string(data_.sequence) +
                      "-frame training sequence of " + std::to_string(data_.crop) + "x" +
                      std::to_string(data_.crop) + " pixels";
    for (const auto& [file, reason] : problems_) why += "\n  " + reason;
    throw RuntimeError(why);
  }
  for (int i = 0; i < data_.readers; ++i) threads_.emplace_back([this] { reader_loop(); });
  scanner_ = std::thread([this] {
    std::unique_lock lock(mu_);
    while (!stop_) {
      auto deadline = std::chrono::steady_clock::now() +
                      std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                          std::chrono::duration<float>(data_.rescan_seconds));
      if (cv_.wait_until(lock, deadline, [&] { return stop_; })) break;
      lock.unlock();
      try {
        rescan();
      } catch (const std::exception& e) {
        spdlog::warn("rescan of {} failed: {}", data_dir_.string(), e.what());
      }
      lock.lock();
    }
  });
}

SequenceStream::~SequenceStream() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  for (auto& t : threads_) t.join();
  if (scanner_.joinable()) scanner_.join();
}

void SequenceStream::rescan() {
  std::vector<std::string> files = list_shards(data_dir_);
  std::vector<std::shared_ptr<const Shard>> added;
  {
    std::lock_guard lock(mu_);
    std::erase_if(files, [&](const std::string& f) {
      if (problems_.count(f)) return true;
      for (const auto& s : shards_)
        if (s->split.file == f) return true;
      return false;
    });
  }
  for (const std::string& f : files) {
    auto shard = std::make_shared<Shard>();
    try {
      shard->reader = std::make_shared<ShardReader>(data_dir_ / f, reader_options_);
      const ShardInfo& info = shard->reader->info();
      if (info.width < data_.crop || info.height < data_.crop)
        throw RuntimeError(f + ": " + std::to_string(info.width) + "x" +
                           std::to_string(info.height) + " frames are smaller than the crop");
      for (const CameraState& c : shard->reader->cameras())
        shard->focal.push_back(c.focal_distance);
    } catch (const std::exception& e) {
      // A corrupted or foreign file must not stop training on the good ones,
      // but it is never silent.
      std::string reason = e.what();
      if (reason.find(f) == std::string::npos) reason = f + ": " + reason;
      spdlog::error("skipping shard: {}", reason);
      std::lock_guard lock(mu_);
      problems_[f] = reason;
      continue;
    }
    std::lock_guard lock(mu_);
    const std::string key = shard_content_key(shard->reader->info());
    const int frames = shard->reader->frame_count();
    auto known = known_splits_.find(key);
    auto legacy = legacy_splits_.find(f);
    if (known != known_splits_.end()) {
      shard->split = known->second;
      shard->split.file = f;  // the same content under another name
    } else if (legacy != legacy_splits_.end() && legacy->second.frames == frames) {
      shard->split = legacy->second;  // a run from before content keys
      shard->split.key = key;
      legacy_splits_.erase(legacy);
    } else {
      shard->split = assign_split(f, key, frames, data_);
    }
    known_splits_[key] = shard->split;
    added.push_back(shard);
  }
  if (added.empty()) return;
  {
    std::lock_guard lock(mu_);
    for (auto& s : added) shards_.push_back(s);
    std::sort(shards_.begin(), shards_.end(),
              [](const auto& a, const auto& b) { return a->split.file < b->split.file; });
  }
  spdlog::info("data: {} new shard(s), {} in total", added.size(), shards_.size());
  save_splits();
}

void SequenceStream::ensure_one_validation_sequence() {
  // A new run whose draws gave no validation sequence at all (a few short
  // shards) takes one from the shard with the lowest draw that keeps a
  // training sequence, so that validation and eval have something to score.
  std::shared_ptr<const Shard> pick;
  double best = 2;
  {
    std::lock_guard lock(mu_);
    for (const auto& sh : shards_) {
      if (sh->split.val_end > sh->split.val_begin) return;  // there is one already
      if (sh->split.frames / data_.sequence < 2) continue;
      const double u = content_draw(sh->split.key);
      if (u < best) best = u, pick = sh;
    }
    if (!pick) return;
    auto changed = std::make_shared<Shard>(*pick);
    changed->split.train_end = changed->split.frames - data_.sequence;
    changed->split.val_begin = changed->split.train_end;
    changed->split.val_end = changed->split.frames;
    known_splits_[changed->split.key] = changed->split;
    for (auto& sh : shards_)
      if (sh == pick) sh = changed;
  }
  spdlog::info("split: no shard drew a validation sequence; {} gives its last {} frames",
               pick->split.file, data_.sequence);
  save_splits();
}

void SequenceStream::save_splits() const {
  json j;
  {
    std::lock_guard lock(mu_);
    j["version"] = 2;
    j["mode"] = data_.split == SplitMode::kShard ? "shard" : "frames";
    j["shards"] = json::object();
    for (const auto& [key, s] : known_splits_)
      j["shards"][key] = {{"file", s.file},
                          {"frames", s.frames},
                          {"train", {s.train_begin, s.train_end}},
                          {"val", {s.val_begin, s.val_end}}};
  }
  fs::create_directories(run_dir_);
  fs::path tmp = run_dir_ / "split.json.tmp", dst = run_dir_ / "split.json";
  {
    std::ofstream out(tmp);
    out << j.dump(1) << "\n";
    if (!out) throw RuntimeError(tmp.string() + ": cannot write");
  }
  fs::rename(tmp, dst);
}

RawCrop SequenceStream::read_raw(const std::string& file, const SequencePlan& plan) const {
  std::shared_ptr<const Shard> shard;
  {
    std::lock_guard lock(mu_);
    for (const auto& s : shards_)
      if (s->split.file == file) shard = s;
  }
  if (!shard) throw RuntimeError(file + ": not a usable shard of " + data_dir_.string());
  const ShardReader& r = *shard->reader;
  const Rect crop{plan.crop_x, plan.crop_y, data_.crop, data_.crop};
  const int f0 = plan.first_frame, n = plan.span;
  RawCrop raw;
  raw.frames = n;
  raw.versions = r.info().versions;
  raw.size = data_.crop;
  // Per-version buffers: only the (frame, version) pairs the plan shows, at
  // most `sequence` of the span x V crops, a V-fold saving in IO and
  // decompression. The others: the span's frames in one read.
  std::vector<std::pair<int, int>> needed;
  for (size_t i = 0; i < plan.offset.size(); ++i)
    needed.emplace_back(plan.offset[i], plan.version[i]);
  std::sort(needed.begin(), needed.end());
  needed.erase(std::unique(needed.begin(), needed.end()), needed.end());
  for (const std::string& name : sample_buffers(model_, data_)) {
    const BufferInfo& b = buffer_info(name);
    if (!b.per_version) {
      raw.buffers[name] = r.read_crop(name, f0, n, 0, crop);
      continue;
    }
    const size_t planes = size_t(b.channels) * raw.size * raw.size;
    std::vector<float>& dst = raw.buffers[name];
    dst.assign(size_t(n) * raw.versions * planes, 0.0f);
    for (const auto& [f, v] : needed)
      r.read_crop_into(name, f0 + f, 1, v, crop, &dst[(size_t(f) * raw.versions + v) * planes]);
  }
  raw.focal_distance.assign(shard->focal.begin() + f0, shard->focal.begin() + f0 + n);
  return raw;
}

Sample SequenceStream::make_sample(uint64_t index, bool validation) const {
  std::mt19937_64 rng(mix(seed_ ^ mix(index) ^ (validation ? kValidationStream : 0)));
  // Pick a shard with probability proportional to the sequences it can start.
  std::vector<std::shared_ptr<const Shard>> pool;
  std::vector<double> weight;
  {
    std::lock_guard lock(mu_);
    for (const auto& s : shards_) {
      int len = validation ? s->split.val_end - s->split.val_begin
                           : s->split.train_end - s->split.train_begin;
      if (len < data_.sequence) continue;
      pool.push_back(s);
      weight.push_back(len - data_.sequence + 1);
    }
  }
  if (pool.empty())
    throw RuntimeError(data_dir_.string() + ": no " +
                       std::string(validation ? "validation" : "training") + " sequences");
  std::discrete_distribution<size_t> pick(weight.begin(), weight.end());
  const Shard& s = *pool[pick(rng)];
  const ShardInfo& info = s.reader->info();
  int begin = validation ? s.split.val_begin : s.split.train_begin;
  int end = validation ? s.split.val_end : s.split.train_end;
  SequencePlan plan = draw_plan(rng, data_, begin, end, info.versions, info.width, info.height);
  RawCrop raw;
  try {
    raw = read_raw(s.split.file, plan);
  } catch (const std::exception& e) {
    std::string what = e.what();
    if (what.find(s.split.file) == std::string::npos) what = s.split.file + ": " + what;
    throw ShardReadFailure(s.split.file, what);
  }
  return build_sample(raw, plan, data_, model_);
}

Sample SequenceStream::make_sample_dropping_bad_shards(uint64_t index, bool validation) {
  for (;;) {
    try {
      return make_sample(index, validation);
    } catch (const ShardReadFailure& e) {
      spdlog::error("dropping shard: {}", e.what());
      std::lock_guard lock(mu_);
      problems_[e.file] = e.what();
      std::erase_if(shards_, [&](const auto& sh) { return sh->split.file == e.file; });
    } catch (const RuntimeError& e) {
      // Nothing left to draw from: say why, with every shard that was dropped.
      std::string why = e.what();
      for (const std::string& p : problems()) why += "\n  " + p;
      throw RuntimeError(why);
    }
  }
}

void SequenceStream::reader_loop() {
  for (;;) {
    uint64_t index;
    {
      std::unique_lock lock(mu_);
      // Bounded: never more than `queue` samples made but not handed out.
      cv_.wait(lock, [&] { return stop_ || claimed_ < next_ + uint64_t(data_.queue); });
      if (stop_) return;
      index = claimed_++;
    }
    try {
      Sample s = make_sample_dropping_bad_shards(index, false);
      std::lock_guard lock(mu_);
      ready_.emplace(index, std::move(s));
    } catch (...) {
      std::lock_guard lock(mu_);
      if (!failure_) failure_ = std::current_exception();
    }
    cv_.notify_all();
  }
}

Sample SequenceStream::next() {
  std::unique_lock lock(mu_);
  cv_.wait(lock, [&] { return failure_ || ready_.count(next_); });
  if (failure_ && !ready_.count(next_)) std::rethrow_exception(failure_);
  Sample s = std::move(ready_.at(next_));
  ready_.erase(next_);
  ++next_;
  lock.unlock();
  cv_.notify_all();
  return s;
}

uint64_t SequenceStream::next_index() const {
  std::lock_guard lock(mu_);
  return next_;
}

uint64_t SequenceStream::held() const {
  std::lock_guard lock(mu_);
  return claimed_ - next_;
}

std::vector<Sample> SequenceStream::validation(int count) {
  std::vector<Sample> out;
  bool any = false;
  for (const ShardSplit& s : splits()) any |= s.val_end - s.val_begin >= data_.sequence;
  if (!any) return out;
  for (int i = 0; i < count; ++i) out.push_back(make_sample_dropping_bad_shards(uint64_t(i), true));
  return out;
}

int64_t SequenceStream::training_sequences() const {
  int64_t n = 0;
  for (const ShardSplit& s : splits()) n += (s.train_end - s.train_begin) / data_.sequence;
  return n;
}

std::vector<ShardSplit> SequenceStream::splits() const {
  std::lock_guard lock(mu_);
  std::vector<ShardSplit> out;
  for (const auto& s : shards_) out.push_back(s->split);
  return out;
}

std::vector<std::string> SequenceStream::problems() const {
  std::lock_guard lock(mu_);
  std::vector<std::string> out;
  for (const auto& [file, reason] : problems_) out.push_back(reason);
  return out;
}

}  // namespace dofarm::trainer
