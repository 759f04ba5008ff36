#include "trainer/batches.h"

#include <algorithm>
#include <chrono>

#include "common/error.h"
#include "trainer/dataset.h"

namespace dofarm::trainer {

namespace {

// Planar (C, S, S) frames into `n` frames of a [N, C, S, S] tensor in
// `format`: NHWC is a transposing copy, NCHW a plain one. Plain loops: this
// runs beside the training step and must not take its intra-op threads.
void copy_frames(const float* src, int frames, int channels, int size, torch::MemoryFormat format,
                 float* dst) {
  const size_t plane = size_t(size) * size;
  if (format != torch::MemoryFormat::ChannelsLast) {
    std::copy(src, src + size_t(frames) * channels * plane, dst);
    return;
  }
  for (int f = 0; f < frames; ++f) {
    const float* s = src + size_t(f) * channels * plane;
    float* d = dst + size_t(f) * channels * plane;
    for (size_t p = 0; p < plane; ++p)
      for (int c = 0; c < channels; ++c) d[p * channels + c] = s[size_t(c) * plane + p];
  }
}

}  // namespace

Batch make_batch(const std::vector<Sample>& samples, torch::Device device,
                 torch::MemoryFormat format) {
  DOFARM_CHECK(!samples.empty());
  const Sample& first = samples[0];
  const int64_t b = int64_t(samples.size()), t = first.frames, s = first.size;
  const int64_t c = first.channels;
  auto frames = [&](int64_t channels) {
    return torch::empty({b * t, channels, s, s},
                        torch::TensorOptions().dtype(torch::kFloat32).memory_format(format));
  };
  torch::Tensor in = frames(c), tg = frames(3);
  const size_t in_stride = size_t(t) * c * s * s, tg_stride = size_t(t) * 3 * s * s;
  for (int64_t i = 0; i < b; ++i) {
    const Sample& x = samples[size_t(i)];
    DOFARM_CHECK(x.frames == t && x.channels == c && x.size == s);
    copy_frames(x.input.data(), int(t), int(c), int(s), format,
                in.data_ptr<float>() + size_t(i) * in_stride);
    copy_frames(x.target.data(), int(t), 3, int(s), format,
                tg.data_ptr<float>() + size_t(i) * tg_stride);
  }
  // [B*T, C, S, S] -> [B, T, C, S, S] splits the outer dimension: a view in
  // either format.
  Batch out;
  out.input = in.view({b, t, c, s, s}).to(device);
  out.target = tg.view({b, t, 3, s, s}).to(device);
  if (!first.coc.empty()) {
    torch::Tensor coc = torch::empty({b, t, 1, s, s});
    for (int64_t i = 0; i < b; ++i) {
      const Sample& x = samples[size_t(i)];
      DOFARM_CHECK_EQ(x.coc.size(), size_t(t) * s * s);
      std::copy(x.coc.begin(), x.coc.end(), coc.data_ptr<float>() + size_t(i) * t * s * s);
    }
    out.coc = coc.to(device);
  }
  return out;
}

BatchPrefetcher::BatchPrefetcher(SequenceStream& stream, int batch, torch::Device device,
                                 torch::MemoryFormat format)
    : stream_(stream), batch_(batch), device_(device), format_(format) {
  pending_ = std::async(std::launch::async, [this] { return assemble(); });
}

BatchPrefetcher::~BatchPrefetcher() {
  if (pending_.valid()) pending_.wait();
}

Batch BatchPrefetcher::assemble() {
  std::vector<Sample> samples;
  for (int i = 0; i < batch_; ++i) samples.push_back(stream_.next());
  Batch b = make_batch(samples, device_, format_);
  b.next_index = stream_.next_index();
  return b;
}

Batch BatchPrefetcher::next() {
  auto t0 = std::chrono::steady_clock::now();
  Batch b = pending_.get();  // rethrows the stream's failure
  waited_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  pending_ = std::async(std::launch::async, [this] { return assemble(); });
  return b;
}

}  // namespace dofarm::trainer
