#include "trainer/config.h"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>

#include "common/error.h"
#include "trainer/inputs.h"

namespace dofarm::trainer {

bool ModelConfig::has_coc() const {
  for (const std::string& e : inputs)
    if (e.rfind("coc:", 0) == 0) return true;
  return false;
}

int ModelConfig::input_channels() const { return input_width(inputs); }

std::vector<int> ModelConfig::effective_channels() const {
  if (!channels.empty()) return channels;
  // Thesis 4.3.1: the CoC model is widened so that the extra input has capacity.
  if (has_coc()) return {36, 48, 64, 85, 113};
  return {32, 43, 57, 76, 101};
}

int ModelConfig::effective_bottleneck() const {
  return bottleneck > 0 ? bottleneck : effective_channels().back();
}

namespace {

// One config key: how to read it from a TOML node, how to write it back, and
// whether changing it makes an existing checkpoint meaningless.
struct Field {
  std::string key;  // "section.name"
  bool affects_model = false;
  // Reads `node` into the config; returns an error message or "".
  std::function<std::string(const toml::node&)> read;
  std::function<void(toml::table&, const std::string&)> write;
  std::vector<std::string>* target_inputs = nullptr;  // model.inputs only (legacy model.dof)
};

// The key model.inputs replaced; still read, never written.
constexpr const char* kLegacyDofKey = "model.dof";

std::string describe(const toml::node& n) {
  std::ostringstream os;
  if (n.is_string()) {
    os << '"' << n.as_string()->get() << '"';
  } else if (n.is_table()) {
    os << "a table";
  } else if (n.is_array()) {
    os << "an array";
  } else {
    n.visit([&](auto&& v) { os << v; });
  }
  return os.str();
}

template <typename T>
Field number_field(std::string key, T* p, double lo, double hi, bool affects_model) {
  Field f;
  f.key = std::move(key);
  f.affects_model = affects_model;
  f.read = [p, lo, hi](const toml::node& n) -> std::string {
    double v = 0;
    if constexpr (std::is_integral_v<T>) {
      if (!n.is_integer())
        return "expected an integer in [" + std::to_string(int64_t(lo)) + ", " +
               std::to_string(int64_t(hi)) + "], got " + describe(n);
      v = double(n.as_integer()->get());
    } else {
      if (!n.is_number()) return "expected a number, got " + describe(n);
      v = n.is_integer() ? double(n.as_integer()->get()) : n.as_floating_point()->get();
    }
    if (!std::isfinite(v) || v < lo || v > hi) {
      std::ostringstream os;
      os << "expected a value in [" << lo << ", " << hi << "], got " << describe(n);
      return os.str();
    }
    *p = static_cast<T>(v);
    return "";
  };
  f.write = [p](toml::table& t, const std::string& name) {
    if constexpr (std::is_integral_v<T>)
      t.insert_or_assign(name, int64_t(*p));
    else if constexpr (std::is_same_v<T, float>)
      // The shortest decimal that reads back as this float (0.8, not
      // 0.800000011920929), as the user wrote it.
      t.insert_or_assign(name, std::stod(fmt::format("{}", *p)));
    else
      t.insert_or_assign(name, double(*p));
  };
  return f;
}

Field bool_field(std::string key, bool* p, bool affects_model) {
  Field f;
  f.key = std::move(key);
  f.affects_model = affects_model;
  f.read = [p](const toml::node& n) -> std::string {
    if (!n.is_boolean()) return "expected true or false, got " + describe(n);
    *p = n.as_boolean()->get();
    return "";
  };
  f.write = [p](toml::table& t, const std::string& name) { t.insert_or_assign(name, *p); };
  return f;
}

template <typename E>
Field enum_field(std::string key, E* p, std::vector<std::pair<std::string, E>> names,
                 bool affects_model) {
  Field f;
  f.key = std::move(key);
  f.affects_model = affects_model;
  f.read = [p, names](const toml::node& n) -> std::string {
    std::string allowed;
    for (const auto& [s, e] : names) allowed += (allowed.empty() ? "" : " | ") + s;
    if (!n.is_string()) return "expected one of " + allowed + ", got " + describe(n);
    for (const auto& [s, e] : names) {
      if (s == n.as_string()->get()) {
        *p = e;
        return "";
      }
    }
    return "expected one of " + allowed + ", got " + describe(n);
  };
  f.write = [p, names](toml::table& t, const std::string& name) {
    for (const auto& [s, e] : names)
      if (e == *p) t.insert_or_assign(name, s);
  };
  return f;
}

Field int_list_field(std::string key, std::vector<int>* p, bool affects_model) {
  Field f;
  f.key = std::move(key);
  f.affects_model = affects_model;
  f.read = [p](const toml::node& n) -> std::string {
    const toml::array* a = n.as_array();
    if (!a) return "expected an array of positive integers, got " + describe(n);
    std::vector<int> out;
    for (const toml::node& e : *a) {
      if (!e.is_integer() || e.as_integer()->get() < 1 || e.as_integer()->get() > 4096)
        return "expected an array of integers in [1, 4096], got element " + describe(e);
      out.push_back(int(e.as_integer()->get()));
    }
    *p = std::move(out);
    return "";
  };
  f.write = [p](toml::table& t, const std::string& name) {
    toml::array a;
    for (int v : *p) a.push_back(int64_t(v));
    t.insert_or_assign(name, std::move(a));
  };
  return f;
}

// model.inputs: entries checked against the input table and stored as
// "name:encoding", so "coc" and "coc:log" are the same config.
Field inputs_field(std::string key, std::vector<std::string>* p) {
  Field f;
  f.key = std::move(key);
  f.affects_model = true;
  f.target_inputs = p;
  f.read = [p](const toml::node& n) -> std::string {
    const toml::array* a = n.as_array();
    if (!a) return "expected an array of input names, got " + describe(n);
    std::vector<std::string> out;
    for (const toml::node& e : *a) {
      if (!e.is_string()) return "expected an array of input names, got element " + describe(e);
      std::string error;
      std::string norm = normalise_input(e.as_string()->get(), &error);
      if (norm.empty()) return error;
      const std::string name = norm.substr(0, norm.find(':'));
      for (const std::string& o : out)
        if (o.substr(0, o.find(':')) == name) return "input '" + name + "' is listed twice";
      out.push_back(norm);
    }
    *p = std::move(out);
    return "";
  };
  f.write = [p](toml::table& t, const std::string& name) {
    toml::array a;
    for (const std::string& v : *p) a.push_back(v);
    t.insert_or_assign(name, std::move(a));
  };
  return f;
}

Field device_field(std::string key, std::string* p) {
  Field f;
  f.key = std::move(key);
  f.read = [p](const toml::node& n) -> std::string {
    if (!n.is_string() || (n.as_string()->get() != "auto" && n.as_string()->get() != "cpu" &&
                           n.as_string()->get() != "cuda"))
      return "expected \"auto\", \"cpu\" or \"cuda\", got " + describe(n);
    *p = n.as_string()->get();
    return "";
  };
  f.write = [p](toml::table& t, const std::string& name) { t.insert_or_assign(name, *p); };
  return f;
}

// The table of every key. Ranges are the sanity limits that turn a typo into an
// error instead of a week of wasted training.
std::vector<Field> fields(TrainConfig& c) {
  constexpr double kBig = 1e9;
  std::vector<Field> f;
  auto& m = c.model;
  f.push_back(inputs_field("model.inputs", &m.inputs));
  f.push_back(int_list_field("model.channels", &m.channels, true));
  f.push_back(number_field("model.bottleneck", &m.bottleneck, 0, 4096, true));
  f.push_back(number_field("model.bottleneck_convs", &m.bottleneck_convs, 1, 16, true));
  f.push_back(enum_field("model.decoder", &m.decoder,
                         {{"project", DecoderForm::kProject}, {"thesis", DecoderForm::kThesis}},
                         true));
  f.push_back(enum_field("model.padding", &m.padding,
                         {{"zeros", PaddingMode::kZeros}, {"replicate", PaddingMode::kReplicate}},
                         true));
  f.push_back(number_field("model.replicate_from", &m.replicate_from, 0, 5, true));
  f.push_back(bool_field("model.recurrent", &m.recurrent, true));
  f.push_back(number_field("model.leaky_slope", &m.leaky_slope, 0.0, 1.0, true));
  auto& d = c.data;
  f.push_back(number_field("data.sequence", &d.sequence, 1, 64, false));
  f.push_back(number_field("data.crop", &d.crop, 32, 4096, false));
  f.push_back(number_field("data.stop_probability", &d.stop_probability, 0.0, 0.95, false));
  f.push_back(number_field("data.reverse_probability", &d.reverse_probability, 0.0, 1.0, false));
  f.push_back(bool_field("data.rotate", &d.rotate, false));
  f.push_back(enum_field(
      "data.albedo", &d.albedo,
      {{"reference", AlbedoSource::kReference}, {"version", AlbedoSource::kVersion}}, true));
  f.push_back(enum_field("data.albedo_prefilter", &d.albedo_prefilter,
                         {{"none", AlbedoPrefilter::kNone}, {"coc", AlbedoPrefilter::kCoc}}, true));
  f.push_back(number_field("data.albedo_prefilter_scale", &d.albedo_prefilter_scale, 0.0, 100.0,
                           true));
  f.push_back(number_field("data.demod_eps", &d.demod_eps, 1e-6, 1.0, true));
  f.push_back(number_field("data.coc_log_scale", &d.coc_log_scale, 1e-3, 100.0, true));
  f.push_back(number_field("data.coc_sharp_px", &d.coc_sharp_px, 0.0, 1e4, true));
  f.push_back(number_field("data.coc_max_px", &d.coc_max_px, 1e-3, 1e5, true));
  f.push_back(number_field("data.depth_scale", &d.depth_scale, 1e-6, 1e9, true));
  f.push_back(enum_field("data.split", &d.split,
                         {{"frames", SplitMode::kFrames}, {"shard", SplitMode::kShard}}, true));
  f.push_back(number_field("data.val_fraction", &d.val_fraction, 0.0, 0.9, true));
  f.push_back(number_field("data.queue", &d.queue, 1, 100000, false));
  f.push_back(number_field("data.readers", &d.readers, 1, 256, false));
  f.push_back(number_field("data.rescan_seconds", &d.rescan_seconds, 0.1, 86400.0, false));
  auto& l = c.loss;
  f.push_back(number_field("loss.l1", &l.l1, 0.0, 1e3, false));
  f.push_back(number_field("loss.log", &l.log, 0.0, 1e3, false));
  f.push_back(enum_field("loss.log_form", &l.log_form,
                         {{"l1", GradientLoss::kL1}, {"thesis", GradientLoss::kThesis}}, false));
  f.push_back(number_field("loss.log_sigma", &l.log_sigma, 0.3, 8.0, false));
  f.push_back(number_field("loss.temporal", &l.temporal, 0.0, 1e3, false));
  f.push_back(number_field("loss.focus_weight", &l.focus_weight, 0.0, 1e3, false));
  f.push_back(number_field("loss.focus_coc_px", &l.focus_coc_px, 1e-3, 1e4, false));
  auto& o = c.train;
  f.push_back(number_field("train.epochs", &o.epochs, 1, kBig, false));
  f.push_back(number_field("train.steps_per_epoch", &o.steps_per_epoch, 0, kBig, false));
  f.push_back(enum_field("train.schedule", &o.schedule,
                         {{"warmup_decay", Schedule::kWarmupDecay}, {"thesis", Schedule::kThesis}},
                         false));
  f.push_back(enum_field("train.best_by", &o.best_by,
                         {{"validation", BestBy::kValidation},
                          {"training", BestBy::kTraining},
                          {"frames", BestBy::kFrames}},
                         false));
  f.push_back(number_field("train.batch", &o.batch, 1, 4096, false));
  f.push_back(number_field("train.lr", &o.lr, 1e-9, 1.0, false));
  f.push_back(number_field("train.beta1", &o.beta1, 0.0, 0.99999, false));
  f.push_back(number_field("train.beta2", &o.beta2, 0.0, 0.99999999, false));
  f.push_back(number_field("train.warmup_steps", &o.warmup_steps, 0, kBig, false));
  f.push_back(number_field("train.lr_decay", &o.lr_decay, 0.01, 1.0, false));
  f.push_back(number_field("train.lr_min", &o.lr_min, 0.0, 1.0, false));
  f.push_back(number_field("train.seed", &o.seed, 0, 9.0e15, true));
  f.push_back(number_field("train.val_sequences", &o.val_sequences, 0, 1000000, false));
  f.push_back(number_field("train.val_frames", &o.val_frames, 0, 1000000, false));
  f.push_back(device_field("train.device", &o.device));
  f.push_back(number_field("train.max_bad_steps", &o.max_bad_steps, 1, 1000000, false));
  f.push_back(number_field("train.grad_clip", &o.grad_clip, 0.0, 1e9, false));
  f.push_back(number_field("train.rollback_lr_factor", &o.rollback_lr_factor, 0.01, 1.0, false));
  f.push_back(number_field("train.ema", &o.ema, 0.0, 0.999999, false));
  f.push_back(number_field("train.cpu_replicas", &o.cpu_replicas, 0, 256, false));
  f.push_back(enum_field("train.precision", &o.precision, precision_names(), false));
  return f;
}

FileLoc loc_of(const toml::node& n, const std::filesystem::path& file) {
  const auto& b = n.source().begin;
  return FileLoc{file.string(), int(b.line), int(b.column)};
}

// Applies `node` to the key `key` or throws a located SpecError.
void apply(std::vector<Field>& fs, const std::string& key, const toml::node& node,
           const FileLoc& loc) {
  if (key == kLegacyDofKey) {
    // Runs from before model.inputs stored `dof = true/false`: the coc input
    // on or off, the other inputs as they are.
    if (!node.is_boolean())
      throw SpecError(loc, key, "expected true or false, got " + describe(node));
    std::vector<std::string>* inputs = nullptr;
    for (Field& f : fs)
      if (f.key == "model.inputs") inputs = f.target_inputs;
    DOFARM_CHECK(inputs != nullptr);
    auto is_coc = [](const std::string& e) { return e.rfind("coc:", 0) == 0; };
    if (!node.as_boolean()->get())
      std::erase_if(*inputs, is_coc);
    else if (std::none_of(inputs->begin(), inputs->end(), is_coc))
      inputs->push_back("coc:log");
    return;
  }
  for (Field& f : fs) {
    if (f.key != key) continue;
    std::string err = f.read(node);
    if (!err.empty()) throw SpecError(loc, key, err);
    return;
  }
  // Like the job spec: say what would have been accepted.
  const std::string section = key.substr(0, key.find('.'));
  std::string allowed;
  for (const Field& f : fs)
    if (f.key.compare(0, section.size() + 1, section + ".") == 0)
      allowed += (allowed.empty() ? "" : ", ") + f.key;
  if (allowed.empty())
    throw SpecError(loc, key, "unknown key (settings live in [model], [data], [loss] or [train])");
  throw SpecError(loc, key, "unknown key; [" + section + "] takes " + allowed);
}

void apply_table(std::vector<Field>& fs, const toml::table& root,
                 const std::filesystem::path& file) {
  for (const auto& [section, node] : root) {
    std::string s(section.str());
    const toml::table* t = node.as_table();
    if (!t) {
      throw SpecError(loc_of(node, file), s,
                      "unknown key (settings live in [model], [data], [loss] or [train])");
    }
    if (s == "model" && t->contains("dof") && t->contains("inputs"))
      throw SpecError(loc_of(*t->get("dof"), file), kLegacyDofKey,
                      "is the old form of model.inputs; give one of the two");
    for (const auto& [name, value] : *t)
      apply(fs, s + "." + std::string(name.str()), value, loc_of(value, file));
  }
}

void check_consistency(const TrainConfig& c, const FileLoc& loc) {
  if (c.data.crop % 32 != 0)
    throw SpecError(
        loc, "data.crop",
        "must be a multiple of 32 (five 2x2 poolings), got " + std::to_string(c.data.crop));
  if (!c.model.channels.empty() && c.model.channels.size() != 5)
    throw SpecError(loc, "model.channels",
                    "expected 5 encoder widths, got " + std::to_string(c.model.channels.size()));
  if (c.train.lr_min > c.train.lr) throw SpecError(loc, "train.lr_min", "must not exceed train.lr");
  if (c.train.best_by == BestBy::kFrames && c.train.val_frames <= 0)
    throw SpecError(loc, "train.best_by",
                    "\"frames\" picks best.pt by the whole validation frames: it needs "
                    "train.val_frames > 0");
  int radiance = 0;
  for (const std::string& e : c.model.inputs) radiance += e.rfind("radiance:", 0) == 0;
  if (radiance != 1)
    throw SpecError(loc, "model.inputs",
                    "must list the noisy radiance (\"radiance\") once: it is what is denoised");
}

TrainConfig parse_impl(const toml::table* root, const std::filesystem::path& file,
                       const std::vector<std::string>& overrides, const TrainConfig* base) {
  TrainConfig cfg = base ? *base : TrainConfig{};
  std::vector<Field> fs = fields(cfg);
  if (root) apply_table(fs, *root, file);
  for (const std::string& ov : overrides) {
    FileLoc loc{"--set " + ov};
    size_t eq = ov.find('=');
    if (eq == std::string::npos || eq == 0)
      throw SpecError(loc, "", "expected KEY=VALUE, e.g. train.epochs=2");
    std::string key = ov.substr(0, eq), value = ov.substr(eq + 1);
    toml::table parsed;
    try {
      parsed = toml::parse("v = " + value);
    } catch (const toml::parse_error&) {
      // An unquoted word (train.device=cuda) is taken as a string.
      parsed = toml::table{{"v", value}};
    }
    apply(fs, key, *parsed.get("v"), loc);
  }
  check_consistency(cfg, FileLoc{file.string()});
  return cfg;
}

}  // namespace

TrainConfig parse_train_config(const std::string& toml_text,
                               const std::filesystem::path& virtual_path,
                               const std::vector<std::string>& overrides,
                               const TrainConfig* base) {
  toml::table root;
  try {
    root = toml::parse(toml_text, virtual_path.string());
  } catch (const toml::parse_error& e) {
    const auto& b = e.source().begin;
    throw SpecError(FileLoc{virtual_path.string(), int(b.line), int(b.column)}, "",
                    std::string(e.description()));
  }
  return parse_impl(&root, virtual_path, overrides, base);
}

std::vector<std::string> preset_names() { return {"default", "thesis"}; }

const std::string& preset_toml(const std::string& name) {
  // Every value the thesis (Petersson 2019) states for its DOF network; what
  // it does not state keeps the project's default (docs/trainer.md,
  // "Thesis preset", lists both).
  static const std::string kThesis = R"(# thesis: Petersson 2019, sections 4.2.4, 4.3 and 5.1
[model]
# 4.3.2 inputs; 4.2.4 encodings: normal listing 1, depth / scene depth,
# CoC listing 2 with the physical CoC in pixels.
inputs = ["radiance:linear", "albedo", "normal:remap01", "depth:scene", "roughness", "coc:thesis"]
bottleneck_convs = 3  # 4.3.1: like the encoder blocks
decoder = "thesis"    # 4.3.1: last block without activation, no output convolution
leaky_slope = 0.1

[data]
sequence = 7
crop = 64
stop_probability = 0.25
reverse_probability = 0.5
albedo = "reference"  # 24-spp albedo (table 5.1's networks)
coc_sharp_px = 1.0
coc_max_px = 32.0
depth_scale = 5.0  # the bundled Cornell box: the back wall is 4.9 units away

[loss]
l1 = 0.8  # eq. 4.2
log = 0.2
log_form = "thesis"  # eq. 4.4

[train]
batch = 4
beta1 = 0.9
beta2 = 0.99
schedule = "thesis"  # eq. 4.5
steps_per_epoch = 0  # an epoch is a pass over the training sequences
best_by = "training"  # 5.1
grad_clip = 0  # the thesis clips nothing
ema = 0  # nor averages the weights
)";
  static const std::string kDefault = "# default: the project's own configuration\n";
  if (name == "thesis") return kThesis;
  if (name == "default") return kDefault;
  std::string names;
  for (const std::string& n : preset_names()) names += (names.empty() ? "" : ", ") + n;
  throw SpecError(FileLoc{"--preset"}, "", "unknown preset '" + name + "'; presets are " + names);
}

TrainConfig apply_preset(const std::string& name, const TrainConfig& base) {
  if (name == "default") return TrainConfig{};
  return parse_train_config(preset_toml(name), "preset:" + name, {}, &base);
}

TrainConfig load_train_config(const std::filesystem::path& path,
                              const std::vector<std::string>& overrides,
                              const TrainConfig* base) {
  if (path.empty()) return parse_impl(nullptr, "", overrides, base);
  std::ifstream in(path);
  if (!in) throw SpecError(FileLoc{path.string()}, "", "cannot open the training config");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_train_config(ss.str(), path, overrides, base);
}

namespace {

// One field's value as TOML text. Floats in their shortest round-trip form
// (0.8, not toml++'s 17-digit 0.80000000000000004).
std::string value_text(const Field& f) {
  toml::table t;
  f.write(t, "v");
  const toml::node& n = *t.get("v");
  if (n.is_floating_point()) {
    std::string s = fmt::format("{}", n.as_floating_point()->get());
    if (s.find_first_of(".e") == std::string::npos) s += ".0";  // stays a float
    return s;
  }
  std::ostringstream os;
  os << t;
  return os.str().substr(4);  // "v = "
}

}  // namespace

std::string to_toml(const TrainConfig& cfg_in) {
  TrainConfig cfg = cfg_in;  // fields() needs mutable pointers; nothing is changed
  std::ostringstream os;
  os << "# Effective training config of this run (written by dofarm-train).\n";
  std::string section;
  for (const Field& f : fields(cfg)) {
    const size_t dot = f.key.find('.');
    if (f.key.substr(0, dot) != section) {
      section = f.key.substr(0, dot);
      os << "\n[" << section << "]\n";
    }
    os << f.key.substr(dot + 1) << " = " << value_text(f) << "\n";
  }
  return os.str();
}

std::vector<std::string> config_changes(const TrainConfig& from_in, const TrainConfig& to_in) {
  TrainConfig from = from_in, to = to_in;
  std::vector<Field> a = fields(from), b = fields(to);
  std::vector<std::string> out;
  for (size_t i = 0; i < a.size(); ++i) {
    const std::string va = value_text(a[i]), vb = value_text(b[i]);
    if (va != vb) out.push_back(a[i].key + ": " + va + " -> " + vb);
  }
  return out;
}

std::string incompatible_reason(const TrainConfig& saved_in, const TrainConfig& wanted_in) {
  TrainConfig saved = saved_in, wanted = wanted_in;
  std::vector<Field> a = fields(saved), b = fields(wanted);
  std::string reason;
  for (size_t i = 0; i < a.size(); ++i) {
    if (!a[i].affects_model) continue;
    const std::string va = value_text(a[i]), vb = value_text(b[i]);
    if (va != vb)
      reason +=
          (reason.empty() ? "" : "; ") + a[i].key + " is " + va + " in the run but " + vb + " now";
  }
  return reason;
}

}  // namespace dofarm::trainer
