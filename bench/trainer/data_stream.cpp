// Throughput of the training data stream (shard crop reads + thesis 4.3.3
// augmentation) by reader-thread count, on synthetic shards written here.
// Prints samples/s; never asserts. Usage: data_stream [samples] [side]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "tests/trainer/synthetic.h"  // the synthetic shards of the trainer tests
#include "trainer/dataset.h"

using namespace dofarm::trainer;
namespace fs = std::filesystem;

int main(int argc, char** argv) {
  const int samples = argc > 1 ? std::max(1, std::atoi(argv[1])) : 200;
  const int side = argc > 2 ? std::max(64, std::atoi(argv[2])) : 256;
  fs::path dir = fs::temp_directory_path() / "dofarm_bench_data_stream";
  fs::remove_all(dir);
  fs::create_directories(dir / "data");
  for (int s = 0; s < 2; ++s) {
    char name[32];
    std::snprintf(name, sizeof name, "shard-%05d.h5", s);
    testing::write_synthetic_shard(dir / "data" / name, 16, side, side, 10, s + 1);
  }
  std::printf("2 shards of 16 frames, %dx%d, 10 versions; %d samples of 7 x 64^2 each\n\n", side,
              side, samples);
  std::printf("| readers | samples/s | ms/sample |\n| --- | --- | --- |\n");
  for (int readers : {1, 2, 4}) {
    DataConfig d;
    d.readers = readers;
    fs::remove_all(dir / "run");
    SequenceStream stream(dir / "data", dir / "run", d, true, 1);
    stream.next();  // first sample: warm caches, start threads
    auto t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < samples; ++i) stream.next();
    double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("| %d | %.1f | %.2f |\n", readers, samples / s, 1e3 * s / samples);
  }
  fs::remove_all(dir);
  return 0;
}
