// Training batches: samples of the stream laid out as one device tensor, and
// the next batch assembled on a background thread while a step runs.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <future>
#include <vector>

#include "trainer/augment.h"

namespace dofarm::trainer {

class SequenceStream;

// One batch on the device: input [B, T, C, S, S] and target [B, T, 3, S, S],
// each frame in `format` (with ChannelsLast the [B*T, C, S, S] view the
// model takes is NHWC without a copy).
struct Batch {
  torch::Tensor input, target;
  torch::Tensor coc;  // [B, T, 1, S, S], pixels; undefined when the samples have none
  uint64_t next_index = 0;  // the stream's next sample after this batch
};
Batch make_batch(const std::vector<Sample>& samples, torch::Device device,
                 torch::MemoryFormat format);

// Assembles the next batch on a background thread while the caller trains on
// the current one, so the step never waits for data (the stream's readers
// make the samples; this takes them in index order and lays them out).
// Single consumer; the stream must outlive it.
class BatchPrefetcher {
 public:
  BatchPrefetcher(SequenceStream& stream, int batch, torch::Device device,
                  torch::MemoryFormat format);
  ~BatchPrefetcher();  // waits for the batch in flight
  BatchPrefetcher(const BatchPrefetcher&) = delete;
  BatchPrefetcher& operator=(const BatchPrefetcher&) = delete;

  // The next batch (rethrows a stream failure); starts on the one after.
  Batch next();
  // Seconds next() has spent waiting for a batch that was not ready yet.
  double waited_seconds() const { return waited_; }

 private:
  Batch assemble();
  SequenceStream& stream_;
  int batch_;
  torch::Device device_;
  torch::MemoryFormat format_;
  std::future<Batch> pending_;
  double waited_ = 0;
};

}  // namespace dofarm::trainer
