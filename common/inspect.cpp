#include "common/inspect.h"

#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/checksum.h"
#include "common/error.h"
#include "common/shard.h"

namespace dofarm {
namespace {
using nlohmann::json;

// Mean and spread merged plane by plane (Chan et al. 1979), so a channel of
// large values over many frames keeps its precision; each plane is two-pass.
struct ChannelStats {
  double min = std::numeric_limits<double>::infinity();
  double max = -std::numeric_limits<double>::infinity();
  double mean = 0, m2 = 0;
  uint64_t count = 0, non_finite = 0;

  void add_plane(const float* v, size_t n) {
    double sum = 0;
    uint64_t k = 0;
    for (size_t i = 0; i < n; ++i) {
      if (!std::isfinite(v[i])) {
        ++non_finite;
        continue;
      }
      sum += v[i];
      ++k;
      min = std::min(min, double(v[i]));
      max = std::max(max, double(v[i]));
    }
    if (k == 0) return;
    double pm = sum / double(k), pm2 = 0;
    for (size_t i = 0; i < n; ++i)
      if (std::isfinite(v[i])) pm2 += (v[i] - pm) * (v[i] - pm);
    double delta = pm - mean;
    uint64_t total = count + k;
    mean += delta * double(k) / double(total);
    m2 += pm2 + delta * delta * double(count) * double(k) / double(total);
    count = total;
  }
  double std_dev() const { return count > 0 ? std::sqrt(m2 / double(count)) : 0.0; }
};

std::string join_dims(const std::vector<uint64_t>& d) {
  std::string s;
  for (size_t i = 0; i < d.size(); ++i) {
    if (i) s += 'x';
    s += std::to_string(d[i]);
  }
  return s.empty() ? "-" : s;
}

std::vector<std::string> split_commas(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');) out.push_back(item);
  return out;
}

json info_json(const ShardInfo& i) {
  return {{"schema", i.schema},
          {"batch_id", i.batch_id},
          {"scene_id", i.scene_id},
          {"scene_hash", i.scene_hash},
          {"job_hash", i.job_hash},
          {"width", i.width},
          {"height", i.height},
          {"versions", i.versions},
          {"spp_noisy", i.spp_noisy},
          {"spp_reference", i.spp_reference},
          {"reference_error", i.reference_error},
          {"spp_albedo_ref", i.spp_albedo_ref},
          {"seed", i.seed},
          {"frame_start", i.frame_start},
          {"frame_end", i.frame_end},
          {"renderer_version", i.renderer_version},
          {"render_seconds", i.render_seconds},
          {"pack_seconds", i.pack_seconds},
          {"created", i.created},
          {"data_checksum", checksum_to_string(i.data_checksum)}};
}

// The report as JSON; the text form is printed from it, so both always agree.
json build_report(const ShardReader& r) {
  const ShardInfo& info = r.info();
  std::map<std::string, std::vector<ChannelStats>> stats;
  for (const BufferInfo& b : buffer_infos()) stats[b.name].resize(b.channels);

  // One frame in memory at a time; the same walk as the stored checksum.
  Checksum64 sum;
  for (int f = 0; f < r.frame_count(); ++f) {
    FrameBuffers fb = r.read_frame(f);
    for (const BufferInfo& b : buffer_infos()) {
      const std::vector<float>& d = buffer_data(fb, b.name);
      size_t planes = d.size() / fb.plane();
      for (size_t p = 0; p < planes; ++p)
        stats[b.name][p % b.channels].add_plane(&d[p * fb.plane()], fb.plane());
      sum.update(d.data(), d.size() * sizeof(float));
    }
    auto row = camera_to_row(fb.camera);
    sum.update(row.data(), size_t(camera_columns_of(info.schema)) * sizeof(float));
  }
  uint64_t computed = sum.digest();

  json datasets = json::array();
  uint64_t non_finite = 0;
  for (const ShardReader::DatasetLayout& l : r.layout()) {
    json d = {{"name", l.name},
              {"shape", l.shape},
              {"chunk", l.chunk},
              {"filters", l.filters},
              {"stored_bytes", l.stored_bytes},
              {"logical_bytes", l.logical_bytes},
              {"compression_ratio",
               l.stored_bytes > 0 ? double(l.logical_bytes) / double(l.stored_bytes) : 0.0}};
    if (l.name == "camera") {
      d["columns"] = split_commas(l.channels);
    } else {
      std::vector<std::string> names = split_commas(l.channels);
      json channels = json::array();
      const std::vector<ChannelStats>& st = stats[l.name];
      for (size_t c = 0; c < st.size(); ++c) {
        bool any = st[c].count > 0;
        channels.push_back({{"name", c < names.size() ? names[c] : std::to_string(c)},
                            {"min", any ? json(st[c].min) : json(nullptr)},
                            {"max", any ? json(st[c].max) : json(nullptr)},
                            {"mean", any ? json(st[c].mean) : json(nullptr)},
                            {"std", any ? json(st[c].std_dev()) : json(nullptr)},
                            {"non_finite", st[c].non_finite}});
        non_finite += st[c].non_finite;
      }
      d["channels"] = channels;
    }
    datasets.push_back(d);
  }
  return {{"file", r.path().string()},
          {"attributes", info_json(info)},
          {"frames", info.frame_count()},
          {"datasets", datasets},
          {"non_finite", non_finite},
          {"data_checksum",
           {{"stored", checksum_to_string(info.data_checksum)},
            {"computed", checksum_to_string(computed)},
            {"ok", computed == info.data_checksum}}}};
}

void print_text(const json& j, std::ostream& out) {
  const json& a = j["attributes"];
  out << j["file"].get<std::string>() << ": " << a["schema"].get<std::string>() << "\n";
  for (const auto& [key, value] : a.items())
    if (key != "schema") out << "  " << std::left << std::setw(18) << key << value.dump() << "\n";
  out << "  frames            " << a["frame_start"] << ".." << a["frame_end"] << " (" << j["frames"]
      << ")\n\n";

  out << std::left << std::setw(15) << "dataset" << std::setw(18) << "shape" << std::setw(16)
      << "chunk" << std::setw(36) << "filters" << std::right << std::setw(12) << "stored"
      << std::setw(8) << "ratio"
      << "\n";
  for (const json& d : j["datasets"]) {
    std::string filters;
    for (const json& f : d["filters"]) {
      if (!filters.empty()) filters += ',';
      filters += f.get<std::string>();
    }
    out << std::left << std::setw(15) << d["name"].get<std::string>() << std::setw(18)
        << join_dims(d["shape"]) << std::setw(16) << join_dims(d["chunk"]) << std::setw(36)
        << filters << std::right << std::setw(12) << d["stored_bytes"].get<uint64_t>()
        << std::setw(8) << std::fixed << std::setprecision(2)
        << d["compression_ratio"].get<double>() << "\n";
  }
  out << "\n"
      << std::left << std::setw(15) << "buffer" << std::setw(8) << "channel" << std::right
      << std::setw(14) << "min" << std::setw(14) << "max" << std::setw(14) << "mean"
      << std::setw(14) << "std" << std::setw(11) << "nan/inf"
      << "\n";
  out << std::defaultfloat << std::setprecision(6);
  auto num = [](const json& v) {
    std::ostringstream os;
    if (v.is_null())
      os << "-";
    else
      os << std::setprecision(6) << v.get<double>();
    return os.str();
  };
  for (const json& d : j["datasets"]) {
    if (!d.contains("channels")) continue;
    for (const json& c : d["channels"])
      out << std::left << std::setw(15) << d["name"].get<std::string>() << std::setw(8)
          << c["name"].get<std::string>() << std::right << std::setw(14) << num(c["min"])
          << std::setw(14) << num(c["max"]) << std::setw(14) << num(c["mean"]) << std::setw(14)
          << num(c["std"]) << std::setw(11) << c["non_finite"].get<uint64_t>() << "\n";
  }
  const json& s = j["data_checksum"];
  out << "\nnon-finite values: " << j["non_finite"].get<uint64_t>() << "\n"
      << "data checksum: " << s["computed"].get<std::string>()
      << (s["ok"].get<bool>() ? " ok" : " MISMATCH, stored " + s["stored"].get<std::string>())
      << "\n";
}

}  // namespace

int inspect_shard(const std::filesystem::path& path, bool as_json, std::ostream& out,
                  std::ostream& err) {
  int code = kExitOk;
  std::string error;
  json report;
  try {
    ShardReader r(path);
    report = build_report(r);
    if (!report["data_checksum"]["ok"].get<bool>() || report["non_finite"].get<uint64_t>() > 0)
      code = kExitRuntime;
  } catch (const ShardFormatError& e) {
    code = kExitBadInput;
    error = e.what();
  } catch (const RuntimeError& e) {
    code = kExitRuntime;
    error = e.what();
  }
  if (!error.empty()) {
    if (as_json)
      out << json{{"file", path.string()}, {"error", error}}.dump(2) << "\n";
    else
      err << "error: " << error << "\n";
    return code;
  }
  if (as_json)
    out << report.dump(2) << "\n";
  else
    print_text(report, out);
  return code;
}

}  // namespace dofarm
