// Throughput of the training data stream (shard crop reads + thesis 4.3.3
// augmentation) by reader-thread count. Prints samples/s; never asserts.
//
//   data_stream [--shard SHARD.h5] [--samples N] [--side S] [--readers 1,2,4] [--hdf5-decode]
//
// --hdf5-decode reads through H5Dread (HDF5 decodes the chunks, under its
// process-wide lock) instead of the reader's own chunk decoding
// (ShardReaderOptions::direct_chunks). CPU ms/sample is the process CPU time
// (all threads) per sample: it is less sensitive than samples/s to other
// work on the machine.
//
// With --shard the stream reads that shard (the same file the h5py pipeline
// of python_baseline.py reads, so the two loaders are compared on equal
// data); without it, on two synthetic shards of S x S written here.
#include <spdlog/spdlog.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "tests/trainer/synthetic.h"  // the synthetic shards of the trainer tests
#include "trainer/dataset.h"

using namespace dofarm::trainer;
namespace fs = std::filesystem;

namespace {
double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
}  // namespace

int main(int argc, char** argv) {
  int samples = 200, side = 256;
  std::string shard;
  std::vector<int> reader_counts = {1, 2, 4};
  dofarm::ShardReaderOptions reader_options;
  for (int i = 1; i < argc; i += 2) {
    std::string k = argv[i], v = i + 1 < argc ? argv[i + 1] : "";
    if (k == "--hdf5-decode") {
      reader_options.direct_chunks = false;
      --i;
    } else if (k == "--shard") {
      shard = v;
    } else if (k == "--samples") {
      samples = std::max(1, std::atoi(v.c_str()));
    } else if (k == "--side") {
      side = std::max(64, std::atoi(v.c_str()));
    } else if (k == "--readers") {
      reader_counts.clear();
      std::stringstream ss(v);
      for (std::string r; std::getline(ss, r, ',');) reader_counts.push_back(std::atoi(r.c_str()));
    } else {
      std::fprintf(stderr,
                   "usage: data_stream [--shard S.h5] [--samples N] [--side S] "
                   "[--readers 1,2,4] [--hdf5-decode]\n");
      return 2;
    }
  }
  spdlog::set_level(spdlog::level::warn);
  fs::path dir =
      fs::temp_directory_path() / ("dofarm_bench_data_stream_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "data");
  if (!shard.empty()) {
    // The stream reads a folder: link the one shard into a private one.
    fs::create_symlink(fs::absolute(shard), dir / "data" / fs::path(shard).filename());
    std::printf("%s; %d samples of 7 x 64^2 each\n\n", shard.c_str(), samples);
  } else {
    for (int s = 0; s < 2; ++s) {
      char name[32];
      std::snprintf(name, sizeof name, "shard-%05d.h5", s);
      testing::write_synthetic_shard(dir / "data" / name, 16, side, side, 10, s + 1);
    }
    std::printf("2 synthetic shards of 16 frames, %dx%d, 10 versions; %d samples of 7 x 64^2\n\n",
                side, side, samples);
  }
  std::printf("chunk decoding: %s\n\n", reader_options.direct_chunks
                                            ? "reader threads (H5Dread_chunk)"
                                            : "HDF5 (H5Dread, under its lock)");
  std::printf("| readers | samples/s | ms/sample | CPU ms/sample |\n| --- | --- | --- | --- |\n");
  for (int readers : reader_counts) {
    DataConfig d;
    d.readers = readers;
    d.val_fraction = 0;  // every frame is a training frame, as in the h5py pipeline
    fs::remove_all(dir / "run");
    SequenceStream stream(dir / "data", dir / "run", d, ModelConfig{}, 1, 0, reader_options);
    stream.next();  // first sample: warm caches, start threads
    auto t0 = std::chrono::steady_clock::now();
    double c0 = cpu_seconds();
    for (int i = 0; i < samples; ++i) stream.next();
    double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    double c = cpu_seconds() - c0;
    std::printf("| %d | %.1f | %.2f | %.2f |\n", readers, samples / s, 1e3 * s / samples,
                1e3 * c / samples);
  }
  fs::remove_all(dir);
  return 0;
}
