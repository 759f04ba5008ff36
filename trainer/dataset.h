// Streaming training data from shards (DESIGN.md "The trainer").
//
// The data folder is a farm output folder: the shards listed in its
// manifest.json (complete by construction), or, without a manifest, every
// *.h5 in it. Background reader threads draw a SequencePlan, read just the
// crop it needs (ShardReader::read_crop) and build the Sample; a rescan picks
// up shards that the farm adds while training runs.
//
// Determinism: sample i is drawn from an RNG seeded by (seed, i), and next()
// hands samples out strictly in index order whatever thread made them, so
// with a fixed set of shards a run (and a resumed run) sees the same data.
// Memory: at most DataConfig::queue samples exist at any time. A shard that
// fails to open or to read is logged with the reason and dropped; the stream
// fails only when no usable shard is left.
//
// Train/validation split: by whole sequences at the end of each shard, or by
// whole shards (DataConfig::split), decided by the shard's content (its data
// checksum), never its file name. The assignment of every shard is written to
// RUN/split.json (keyed by that checksum) the first time the shard is seen and
// reused on resume, so the two sets never overlap, even while new shards
// arrive, and a new shard that reuses an old file name is a new shard.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "common/shard.h"
#include "trainer/augment.h"
#include "trainer/config.h"

namespace dofarm::trainer {

// Frame ranges [begin, end) of one shard; an empty range has begin == end.
struct ShardSplit {
  std::string file;  // name inside the data folder (for people; not the key)
  std::string key;   // the shard's data checksum ("xxh64:..."): what identifies it
  int frames = 0;
  int train_begin = 0, train_end = 0;
  int val_begin = 0, val_end = 0;
  bool operator==(const ShardSplit&) const = default;
};

// The split of a shard seen for the first time (pure: same input, same split).
// "frames": of the K = frames / sequence whole sequences, floor(K f) + b are
// validation (f = val_fraction), where b is 1 with probability frac(K f)
// drawn from the content key, so the expected share of validation sequences
// is exactly f; they are the last n * sequence frames. "shard": the whole
// shard is validation with probability f, drawn from the key.
ShardSplit assign_split(const std::string& file, const std::string& key, int frames,
                        const DataConfig& data);

// RUN/split.json as written by SequenceStream, keyed by content key; empty
// when there is none. Entries of the first format (keyed by file name) are
// returned with an empty key and their file name.
std::vector<ShardSplit> load_split_file(const std::filesystem::path& run_dir);
std::string shard_content_key(const ShardInfo& info);

// Shard file names of a data folder (manifest first), sorted.
std::vector<std::string> list_shards(const std::filesystem::path& data_dir);

class SequenceStream {
 public:
  // Scans `data_dir` once (synchronously), loads/extends RUN/split.json and
  // starts the readers; the first sample handed out is `first_index`. Throws
  // RuntimeError naming the folder when no shard holds a training sequence,
  // with each unusable shard and why.
  SequenceStream(std::filesystem::path data_dir, std::filesystem::path run_dir, DataConfig data,
                 ModelConfig model, uint64_t seed, uint64_t first_index = 0,
                 ShardReaderOptions reader_options = {});
  ~SequenceStream();
  SequenceStream(const SequenceStream&) = delete;
  SequenceStream& operator=(const SequenceStream&) = delete;

  // The next sample in index order; blocks until a reader has made it.
  // Rethrows a reader's failure.
  Sample next();
  uint64_t next_index() const;
  // Samples made or being made but not yet handed out: the stream's memory,
  // never more than data.queue whatever the size of the data.
  uint64_t held() const;

  // `count` validation samples, the same ones every call while the shard set
  // is unchanged (seeded by index, independent of the training stream).
  std::vector<Sample> validation(int count);

  // Current split (for eval and for the run folder).
  std::vector<ShardSplit> splits() const;
  // Whole training sequences (data.sequence consecutive frames) of the
  // current split: the size of one pass over the training data (thesis 4.3.3
  // chunks the frames into sequences).
  int64_t training_sequences() const;
  // Shards skipped because they could not be read, with the reason.
  std::vector<std::string> problems() const;

  // Reads an arbitrary plan's raw crop (also used by tests).
  RawCrop read_raw(const std::string& file, const SequencePlan& plan) const;

 private:
  struct Shard {
    ShardSplit split;
    std::shared_ptr<ShardReader> reader;
    std::vector<float> focal;  // per frame
  };
  void rescan();
  void reader_loop();
  Sample make_sample(uint64_t index, bool validation) const;
  // make_sample(), dropping (and logging) a shard that fails while read.
  Sample make_sample_dropping_bad_shards(uint64_t index, bool validation);
  void save_splits() const;
  void ensure_one_validation_sequence();

  std::filesystem::path data_dir_, run_dir_;
  DataConfig data_;
  ShardReaderOptions reader_options_;
  ModelConfig model_;  // its inputs decide which buffers are read
  uint64_t seed_;

  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::vector<std::shared_ptr<const Shard>> shards_;  // sorted by file
  std::map<std::string, ShardSplit> known_splits_;    // by content key, from split.json
  std::map<std::string, ShardSplit> legacy_splits_;   // by file, split.json format 1
  std::map<std::string, std::string> problems_;       // file -> reason
  std::map<uint64_t, Sample> ready_;
  uint64_t next_ = 0;     // next index handed out
  uint64_t claimed_ = 0;  // next index a reader will make
  std::exception_ptr failure_;
  bool stop_ = false;
  std::vector<std::thread> threads_;
  std::thread scanner_;
};

}  // namespace dofarm::trainer
