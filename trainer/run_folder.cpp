#include "trainer/run_folder.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "common/content_hash.h"
#include "common/error.h"
#include "common/file_bytes.h"

namespace dofarm::trainer {

namespace fs = std::filesystem;

namespace {

constexpr const char* kMagic = "dofarm-checkpoint";
constexpr int kVersion = 1;
// A checkpoint of the thesis model with Adam state is about 10 MB; this
// bounds what a damaged size field can make the loader allocate.
constexpr uint64_t kMaxCheckpointBytes = uint64_t(4) << 30;

bool all_finite(const torch::nn::Module& m) {
  for (const auto& p : m.parameters())
    if (!torch::isfinite(p).all().item<bool>()) return false;
  return true;
}

void fsync_dir(const fs::path& dir) {
  const int fd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

// `bytes` to `path` atomically: a fresh temporary beside it, fsynced, renamed.
void replace_file(const fs::path& path, std::string_view bytes) {
  fs::path tmp = path;
  tmp += ".tmp";
  std::error_code ec;
  fs::remove(tmp, ec);  // left by a crash mid-write
  write_new_file(tmp, bytes);
  fs::rename(tmp, path);
  fsync_dir(path.parent_path());
}

[[noreturn]] void damaged(const fs::path& path, const std::string& why) {
  throw RuntimeError(path.string() + ": damaged checkpoint: " + why +
                     "; nothing was loaded (use another checkpoint, e.g. --checkpoint last or "
                     "a checkpoints/step-*.pt file)");
}

// The run state and config into `ar`, then header + archive to `path`, atomically.
void write_state_and_save(const fs::path& path, torch::serialize::OutputArchive& ar,
                          const RunState& st, const TrainConfig& cfg) {
  ar.write("state", torch::tensor({st.epoch, st.step, st.sample_index}, torch::kInt64));
  ar.write("state_f", torch::tensor({st.lr_scale, st.best}, torch::kFloat64));
  ar.write("config", c10::IValue(to_toml(cfg)));
  std::string payload;
  ar.save_to([&payload](const void* data, size_t n) {
    payload.append(static_cast<const char*>(data), n);
    return n;
  });
  std::string file =
      fmt::format("{} {} {} {}\n", kMagic, kVersion, content_hash(payload), payload.size());
  file += payload;
  replace_file(path, file);
}

}  // namespace

void write_text_atomic(const fs::path& p, const std::string& text) { replace_file(p, text); }

void save_checkpoint(const fs::path& path, Denoiser& model, torch::optim::Adam& opt,
                     const RunState& st, const TrainConfig& cfg, Denoiser* average) {
  // No NaN/Inf ever reaches a checkpoint: a model that diverged is not saved.
  if (!all_finite(*model) || (average && !all_finite(**average)))
    throw RuntimeError("refusing to checkpoint non-finite weights");
  torch::serialize::OutputArchive ar, m, o, a;
  model->save(m);
  opt.save(o);
  ar.write("model", m);
  ar.write("optimizer", o);
  if (average) {
    (*average)->save(a);
    ar.write("average", a);
  }
  write_state_and_save(path, ar, st, cfg);
}

void save_weights_checkpoint(const fs::path& path, LoadedRun& run) {
  if (!all_finite(*run.model)) throw RuntimeError("refusing to checkpoint non-finite weights");
  torch::serialize::OutputArchive ar, w;
  run.model->save(w);
  // Under the key they were read from, so that --weights means the same.
  ar.write(run.averaged ? "average" : "model", w);
  write_state_and_save(path, ar, run.state, run.config);
}

namespace {

// The checkpoint's archive, after its header and content hash are verified.
void open_archive(const fs::path& path, torch::Device device, torch::serialize::InputArchive& ar) {
  std::string file;
  try {
    file = read_regular_file(path, kMaxCheckpointBytes);
  } catch (const RuntimeError& e) {
    throw RuntimeError(std::string(e.what()) + " (checkpoint)");
  }
  // Header: magic, version, hash, size; then exactly `size` payload bytes.
  const size_t eol = file.find('\n');
  if (eol == std::string::npos || eol > 200 || file.compare(0, std::strlen(kMagic), kMagic) != 0)
    damaged(path, "not a dofarm checkpoint (no \"dofarm-checkpoint\" header)");
  std::istringstream header(file.substr(0, eol));
  std::string magic, hash;
  int version = 0;
  uint64_t size = 0;
  header >> magic >> version >> hash >> size;
  if (!header || magic != kMagic) damaged(path, "unreadable header");
  if (version != kVersion)
    damaged(path, "format version " + std::to_string(version) + " (this build reads " +
                      std::to_string(kVersion) + ")");
  const std::string_view payload = std::string_view(file).substr(eol + 1);
  if (payload.size() != size)
    damaged(path, fmt::format("{} payload bytes where the header records {} (truncated?)",
                              payload.size(), size));
  const std::string actual = content_hash(payload);
  if (actual != hash)
    damaged(path, "content hash " + actual + " does not match the recorded " + hash +
                      " (the file changed after it was written)");
  try {
    ar.load_from(payload.data(), payload.size(), device);
  } catch (const c10::Error& e) {
    damaged(path, std::string("cannot read the archive: ") + e.what_without_backtrace());
  }
}

// Whether the archive has an entry `key` (weights, optimizer state, ...).
bool has_entry(torch::serialize::InputArchive& ar, const std::string& key) {
  const std::vector<std::string> keys = ar.keys();
  return std::find(keys.begin(), keys.end(), key) != keys.end();
}

// The archive's weights `key` into `model`; false when it has no such entry.
bool read_weights(torch::serialize::InputArchive& ar, const std::string& key, Denoiser& model,
                  const fs::path& path) {
  torch::serialize::InputArchive m;
  try {
    if (!ar.try_read(key, m)) return false;
  } catch (const c10::Error& e) {
    damaged(path, std::string("cannot read the archive: ") + e.what_without_backtrace());
  }
  try {
    model->load(m);
  } catch (const c10::Error& e) {
    // The checksum held, so the file is as written: it is another model.
    throw RuntimeError(path.string() + ": the checkpoint's weights do not fit the run's model "
                       "(model.* keys differ from the run that wrote it): " +
                       e.what_without_backtrace());
  }
  // load() adopts the stored tensors' strides: back to the model's format.
  model->set_memory_format(model->memory_format());
  if (!all_finite(*model)) damaged(path, "non-finite weights (" + key + ")");
  return true;
}

RunState read_state(torch::serialize::InputArchive& ar, const fs::path& path) {
  torch::Tensor s, f;
  try {
    ar.read("state", s);
    ar.read("state_f", f);
  } catch (const c10::Error& e) {
    damaged(path, std::string("cannot read the archive: ") + e.what_without_backtrace());
  }
  s = s.to(torch::kCPU);
  f = f.to(torch::kCPU);
  if (s.numel() != 3 || f.numel() != 2) damaged(path, "state record of the wrong size");
  RunState st;
  st.epoch = s[0].item<int64_t>();
  st.step = s[1].item<int64_t>();
  st.sample_index = s[2].item<int64_t>();
  st.lr_scale = f[0].item<double>();
  st.best = f[1].item<double>();
  if (st.epoch < 0 || st.step < 0 || st.sample_index < 0 || !(st.lr_scale > 0) ||
      !std::isfinite(st.lr_scale) || std::isnan(st.best))
    damaged(path, "state out of range");
  return st;
}

}  // namespace

void copy_weights(Denoiser& dst, Denoiser& src) {
  torch::NoGradGuard no_grad;
  const auto from = src->parameters();
  auto to = dst->parameters();
  if (from.size() != to.size())
    throw RuntimeError("copy_weights: the two models differ in their parameters");
  for (size_t i = 0; i < to.size(); ++i) to[i].copy_(from[i]);
}

RunState load_checkpoint(const fs::path& path, Denoiser& model, torch::optim::Adam* opt,
                         torch::Device device, Denoiser* average, bool* had_average) {
  torch::serialize::InputArchive ar;
  open_archive(path, device, ar);
  if (opt && !has_entry(ar, "optimizer"))
    throw RuntimeError(path.string() +
                       ": holds weights only (export --format checkpoint, for evaluation): "
                       "training cannot resume from it");
  if (!read_weights(ar, "model", model, path)) damaged(path, "no model weights");
  if (opt) {
    try {
      torch::serialize::InputArchive o;
      ar.read("optimizer", o);
      opt->load(o);
    } catch (const c10::Error& e) {
      damaged(path, std::string("cannot read the archive: ") + e.what_without_backtrace());
    }
    for (const auto& group : opt->state())
      for (const auto& t : {static_cast<torch::optim::AdamParamState&>(*group.second).exp_avg(),
                            static_cast<torch::optim::AdamParamState&>(*group.second).exp_avg_sq()})
        if (t.defined() && !torch::isfinite(t).all().item<bool>())
          damaged(path, "non-finite optimizer state");
  }
  if (average) {
    const bool had = read_weights(ar, "average", *average, path);
    if (!had) copy_weights(*average, model);
    if (had_average) *had_average = had;
  }
  return read_state(ar, path);
}

torch::Device pick_device(const std::string& device) {
  if (device == "cpu") return torch::kCPU;
  if (torch::cuda::is_available()) return torch::kCUDA;
  if (device == "cuda") throw RuntimeError("train.device is \"cuda\" but no CUDA device is usable");
  return torch::kCPU;
}

fs::path checkpoint_path(const fs::path& run_dir, const std::string& which) {
  const fs::path dir = run_dir / "checkpoints";
  if (which == "best") {
    if (fs::exists(dir / "best.pt")) return dir / "best.pt";
    return dir / "last.pt";
  }
  if (which == "last") return dir / "last.pt";
  if (which.empty()) throw SpecError(FileLoc{"--checkpoint"}, "", "empty checkpoint name");
  return fs::path(which);
}

const NameTable<Weights>& weights_names() {
  static const NameTable<Weights> names = {
      {"auto", Weights::kAuto}, {"averaged", Weights::kAveraged}, {"raw", Weights::kRaw}};
  return names;
}

LoadedRun load_run(const fs::path& run_dir, torch::Device device, const std::string& which,
                   Weights weights) {
  LoadedRun r;
  if (!fs::exists(run_dir / "config.toml"))
    throw SpecError(FileLoc{run_dir.string()}, "", "not a training run (no config.toml)");
  r.config = parse_train_config(read_file_bytes(run_dir / "config.toml"), run_dir / "config.toml");
  r.checkpoint = checkpoint_path(run_dir, which);
  if (!fs::exists(r.checkpoint))
    throw SpecError(FileLoc{r.checkpoint.string()}, "",
                    which == "best" || which == "last" ? "the run has no checkpoint yet"
                                                       : "no such checkpoint file");
  r.model = Denoiser(r.config.model);
  r.model->to(device);
  r.model->set_memory_format(preferred_memory_format(device));
  torch::serialize::InputArchive ar;
  open_archive(r.checkpoint, device, ar);
  r.averaged = weights != Weights::kRaw && read_weights(ar, "average", r.model, r.checkpoint);
  if (weights == Weights::kAveraged && !r.averaged)
    throw SpecError(FileLoc{r.checkpoint.string()}, "",
                    "the checkpoint holds no moving average of the weights (the run trained "
                    "with train.ema = 0); use --weights raw or auto");
  if (!r.averaged && !read_weights(ar, "model", r.model, r.checkpoint)) {
    if (has_entry(ar, "average"))
      throw SpecError(FileLoc{r.checkpoint.string()}, "",
                      "holds only the moving average of the weights (export --format "
                      "checkpoint); use --weights auto or averaged");
    damaged(r.checkpoint, "no model weights");
  }
  r.state = read_state(ar, r.checkpoint);
  r.model->eval();
  return r;
}

}  // namespace dofarm::trainer
