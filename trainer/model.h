// The denoiser: the convolutional autoencoder of thesis 4.3.1 (after
// Chaitanya et al. 2017), with their recurrent encoder blocks as an option.
//
//   encoder i = 0..4: [concat hidden_i] -> 3 x (conv3x3 + LeakyReLU) -> skip_i -> maxpool2x2
//   bottleneck:       model.bottleneck_convs x (conv3x3 + LeakyReLU) at 1/32 resolution
//   decoder i = 4..0: nearest upsample x2 -> concat skip_i -> 2 x conv3x3, then
//     model.decoder = "project": both to width_i with LeakyReLU; then an
//                                output conv3x3 -> 3 channels, linear
//     model.decoder = "thesis":  width_i, then width_{i-1} (3 for i = 0), with
//                                LeakyReLU except in block 0, which is linear
//                                and is the output (thesis 4.3.1, fig. 4.3)
// The output is transformed demodulated radiance (trainer/inputs.h).
//
// Frame sides must be multiples of 32 (five poolings); pad_to_multiple() pads
// full frames for inference. In the recurrent model the output of encoder
// block i at frame t is its hidden state at frame t + 1 (zeros at t = 0).
#pragma once

#include <torch/torch.h>

#include <filesystem>
#include <map>
#include <vector>

#include "trainer/config.h"

namespace dofarm::trainer {

inline constexpr int kLevels = 5;
inline constexpr int kSizeMultiple = 32;  // 2^kLevels

class DenoiserImpl : public torch::nn::Module {
 public:
  explicit DenoiserImpl(const ModelConfig& cfg);

  // seq: [B, T, C, H, W] -> [B, T, 3, H, W]. The recurrent model runs the
  // frames in order from a zero state; the plain one treats them independently.
  torch::Tensor forward(const torch::Tensor& seq);

  // One frame [B, C, H, W]. `state` holds the hidden state per encoder level;
  // empty on the first frame, updated in place (ignored when not recurrent).
  torch::Tensor forward_frame(const torch::Tensor& x, std::vector<torch::Tensor>& state);

  const ModelConfig& config() const { return cfg_; }

  // Diagnostics (bench/trainer/crop_vs_frame --taps): while set, every
  // forward_frame appends to *taps each encoder level's output (before its
  // pooling, levels 0..kLevels-1) and then the bottleneck's, detached.
  void set_taps(std::vector<torch::Tensor>* taps) { taps_ = taps; }

  // Memory format of the activations and convolution weights. It changes no
  // value (up to float summation order) but the speed: on the CPU oneDNN's
  // convolutions work in NHWC (ChannelsLast), so NCHW tensors are reordered
  // into it and back around every convolution, forward and backward.
  // Converts the weights in place; call before creating the optimizer's state
  // (Adam's moments take the layout of their parameter when first made).
  // Outputs come in this format; call .contiguous() before raw pointer access.
  void set_memory_format(torch::MemoryFormat format);
  torch::MemoryFormat memory_format() const { return format_; }

  // A TorchScript module with the same weights and arithmetic, loadable by
  // torch.jit.load in Python or torch::jit::load in C++. Its forward takes one
  // frame [B, C, H, W] of any size (padded inside by edge replication to a
  // multiple of kSizeMultiple, the output cropped back); with the recurrent
  // model also the five hidden states at the padded size (zeros on the first
  // frame) and it returns (output, states...). `extra_files` are stored in
  // the archive (torch.jit.load(..., _extra_files=...) reads them).
  void export_torchscript(const std::filesystem::path& path,
                          const std::map<std::string, std::string>& extra_files = {}) const;

 private:
  struct Conv {
    torch::nn::Conv2d conv{nullptr};
    std::string name;
    bool activate = true;    // LeakyReLU after it
    bool replicate = false;  // replicate padding (model.padding, model.replicate_from)
  };
  // `level`: the resolution it works at, 1/2^level (kLevels: the bottleneck).
  Conv add_conv(const std::string& name, int level, int in, int out, bool activate = true);
  // c's convolution of h, padded as model.padding says.
  torch::Tensor conv(Conv& c, const torch::Tensor& h);
  torch::Tensor act(torch::Tensor x) const;  // on a convolution output, in place

  ModelConfig cfg_;
  torch::MemoryFormat format_ = torch::MemoryFormat::Contiguous;
  std::vector<int> widths_;
  int bottleneck_ = 0;
  std::vector<torch::Tensor>* taps_ = nullptr;
  std::vector<std::vector<Conv>> enc_, dec_;
  std::vector<Conv> mid_;
  Conv out_;  // null with the thesis decoder
};
TORCH_MODULE(Denoiser);

// The faster memory format on `device`: ChannelsLast on the CPU (oneDNN);
// Contiguous (NCHW) elsewhere (float32 cuDNN convolutions gain little from
// NHWC without tensor cores).
torch::MemoryFormat preferred_memory_format(torch::Device device);

// Pads [.., H, W] with edge replication on the bottom and right to multiples
// of kSizeMultiple; crop back with narrow().
torch::Tensor pad_to_multiple(const torch::Tensor& x);
// One pixel of edge replication on each side of an N x C x H x W tensor
// (model.padding = "replicate"): the values and the gradient of
// replication_pad2d(x, {1, 1, 1, 1}), at a fraction of its CPU backward's cost.
torch::Tensor replicate_pad1(const torch::Tensor& x);

// Number of trainable parameters.
int64_t parameter_count(const torch::nn::Module& m);

}  // namespace dofarm::trainer
