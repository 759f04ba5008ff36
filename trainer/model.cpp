#include "trainer/model.h"

#include <torch/script.h>

#include <sstream>

#include "common/error.h"

namespace dofarm::trainer {

namespace {
// "e2_1": block `kind` (e encoder, d decoder) `level`, convolution `index`;
// the parameter names checkpoints and the export use.
std::string layer_name(char kind, int level, int index) {
  std::string s(1, kind);
  s += std::to_string(level);
  s += '_';
  s += std::to_string(index);
  return s;
}
}  // namespace

DenoiserImpl::DenoiserImpl(const ModelConfig& cfg)
    : cfg_(cfg), widths_(cfg.effective_channels()), bottleneck_(cfg.effective_bottleneck()) {
  DOFARM_CHECK_EQ(int(widths_.size()), kLevels);
  const bool thesis = cfg.decoder == DecoderForm::kThesis;
  int in = cfg.input_channels();
  enc_.resize(kLevels);
  for (int i = 0; i < kLevels; ++i) {
    const int w = widths_[i];
    // Recurrent block (Chaitanya 2017, fig. 3): the previous frame's block
    // output is concatenated with this frame's block input.
    const int first_in = in + (cfg.recurrent ? w : 0);
    enc_[i].push_back(add_conv(layer_name('e', i, 0), i, first_in, w));
    enc_[i].push_back(add_conv(layer_name('e', i, 1), i, w, w));
    enc_[i].push_back(add_conv(layer_name('e', i, 2), i, w, w));
    in = w;
  }
  // Thesis 4.3.1: the bottleneck is like an encoder block whose convolutions
  // keep the channel count.
  for (int k = 0; k < cfg.bottleneck_convs; ++k) {
    mid_.push_back(add_conv("m_" + std::to_string(k), kLevels, in, bottleneck_));
    in = bottleneck_;
  }
  dec_.resize(kLevels);
  for (int i = kLevels - 1; i >= 0; --i) {
    const int w = widths_[i];
    if (thesis) {
      // The first convolution halves the concatenation back to this level's
      // width, the second gives the next level's (3 channels at the end);
      // the last block has no activation (thesis 4.3.1, fig. 4.3).
      const int next = i > 0 ? widths_[i - 1] : 3;
      dec_[i].push_back(add_conv(layer_name('d', i, 0), i, in + w, w, i > 0));
      dec_[i].push_back(add_conv(layer_name('d', i, 1), i, w, next, i > 0));
      in = next;
    } else {
      dec_[i].push_back(add_conv(layer_name('d', i, 0), i, in + w, w));
      dec_[i].push_back(add_conv(layer_name('d', i, 1), i, w, w));
      in = w;
    }
  }
  if (!thesis) out_ = add_conv("out", 0, in, 3, false);
}

DenoiserImpl::Conv DenoiserImpl::add_conv(const std::string& name, int level, int in, int out,
                                          bool activate) {
  Conv c;
  c.name = name;
  c.activate = activate;
  c.replicate = cfg_.padding == PaddingMode::kReplicate && level >= cfg_.replicate_from;
  // Replicate padding is applied by conv() (replicate_pad1), the
  // convolution itself then pads nothing.
  const int pad = c.replicate ? 0 : 1;
  c.conv =
      register_module(name, torch::nn::Conv2d(torch::nn::Conv2dOptions(in, out, 3).padding(pad)));
  // He initialisation for leaky ReLU keeps activations at unit scale through
  // the 24 convolutions.
  torch::nn::init::kaiming_normal_(c.conv->weight, cfg_.leaky_slope, torch::kFanIn,
                                   torch::kLeakyReLU);
  torch::nn::init::zeros_(c.conv->bias);
  return c;
}

void DenoiserImpl::set_memory_format(torch::MemoryFormat format) {
  format_ = format;
  torch::NoGradGuard no_grad;
  for (auto& p : parameters())
    if (p.dim() == 4) p.set_data(p.data().contiguous(format));
}

namespace {

// One pixel of replicate padding on each side of H and W. ATen's
// replication_pad2d backward on the CPU made a training step about three
// times as long as with zero padding; here the border's gradient is folded
// onto the edge pixels with a copy and four slice additions.
struct ReplicatePad1 : torch::autograd::Function<ReplicatePad1> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x) {
    const int64_t h = x.size(2), w = x.size(3);
    ctx->saved_data["h"] = h;
    ctx->saved_data["w"] = w;
    torch::Tensor y = torch::empty({x.size(0), x.size(1), h + 2, w + 2},
                                   x.options().memory_format(x.suggest_memory_format()));
    torch::Tensor rows = y.narrow(2, 1, h);
    rows.narrow(3, 1, w).copy_(x);
    rows.select(3, 0).copy_(x.select(3, 0));
    rows.select(3, w + 1).copy_(x.select(3, w - 1));
    y.select(2, 0).copy_(y.select(2, 1));
    y.select(2, h + 1).copy_(y.select(2, h));
    return y;
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grad) {
    const int64_t h = ctx->saved_data["h"].toInt(), w = ctx->saved_data["w"].toInt();
    const torch::Tensor& g = grad[0];  // N x C x (h + 2) x (w + 2)
    torch::Tensor cols = g.narrow(3, 1, w).clone(torch::MemoryFormat::Preserve);
    cols.select(3, 0).add_(g.select(3, 0));
    cols.select(3, w - 1).add_(g.select(3, w + 1));
    torch::Tensor out = cols.narrow(2, 1, h).clone(torch::MemoryFormat::Preserve);
    out.select(2, 0).add_(cols.select(2, 0));
    out.select(2, h - 1).add_(cols.select(2, h + 1));
    return {out};
  }
};

}  // namespace

torch::Tensor replicate_pad1(const torch::Tensor& x) { return ReplicatePad1::apply(x); }

torch::Tensor DenoiserImpl::conv(Conv& c, const torch::Tensor& h) {
  return c.replicate ? c.conv->forward(replicate_pad1(h)) : c.conv->forward(h);
}

torch::Tensor DenoiserImpl::act(torch::Tensor x) const {
  // In place on the convolution's fresh output (which the convolution's
  // backward does not need): one activation buffer fewer per layer.
  return torch::leaky_relu_(x, cfg_.leaky_slope);  // thesis 4.2: slope 0.1
}

torch::Tensor DenoiserImpl::forward_frame(const torch::Tensor& x,
                                          std::vector<torch::Tensor>& state) {
  DOFARM_CHECK_EQ(x.size(1), int64_t(cfg_.input_channels()));
  DOFARM_CHECK_EQ(x.size(2) % kSizeMultiple, 0);
  DOFARM_CHECK_EQ(x.size(3) % kSizeMultiple, 0);
  std::vector<torch::Tensor> skips;
  torch::Tensor h = x.contiguous(format_);  // no copy when already in the format
  if (cfg_.recurrent && state.empty()) {
    for (int i = 0; i < kLevels; ++i)
      state.push_back(torch::zeros({x.size(0), widths_[i], x.size(2) >> i, x.size(3) >> i},
                                   x.options().memory_format(format_)));
  }
  for (int i = 0; i < kLevels; ++i) {
    if (cfg_.recurrent) h = torch::cat({h, state[i]}, 1);
    for (auto& c : enc_[i]) h = act(conv(c, h));
    if (cfg_.recurrent) state[i] = h;
    skips.push_back(h);
    if (taps_) taps_->push_back(h.detach());
    h = torch::max_pool2d(h, {2, 2});
  }
  for (auto& c : mid_) h = act(conv(c, h));
  if (taps_) taps_->push_back(h.detach());
  for (int i = kLevels - 1; i >= 0; --i) {
    h = torch::upsample_nearest2d(h, {h.size(2) * 2, h.size(3) * 2});  // nearest x2
    h = torch::cat({h, skips[i]}, 1);
    for (auto& c : dec_[i]) {
      h = conv(c, h);
      if (c.activate) h = act(h);
    }
  }
  return out_.conv ? conv(out_, h) : h;
}

torch::Tensor DenoiserImpl::forward(const torch::Tensor& seq) {
  DOFARM_CHECK_EQ(seq.dim(), int64_t(5));
  const int64_t b = seq.size(0), t = seq.size(1);
  if (!cfg_.recurrent) {
    torch::Tensor flat = seq.reshape({b * t, seq.size(2), seq.size(3), seq.size(4)});
    std::vector<torch::Tensor> none;
    torch::Tensor y = forward_frame(flat, none);
    return y.reshape({b, t, 3, seq.size(3), seq.size(4)});
  }
  std::vector<torch::Tensor> state, outs;
  for (int64_t i = 0; i < t; ++i) outs.push_back(forward_frame(seq.select(1, i), state));
  return torch::stack(outs, 1);
}

void DenoiserImpl::export_torchscript(const std::filesystem::path& path,
                                     const std::map<std::string, std::string>& extra_files) const {
  torch::jit::Module m("DofarmDenoiser");
  auto reg = [&](const Conv& c) {
    // NCHW weights: the export does not depend on the training layout.
    m.register_parameter(c.name + "_w",
                         c.conv->weight.detach().to(torch::kCPU).contiguous().clone(), false);
    m.register_parameter(c.name + "_b", c.conv->bias.detach().to(torch::kCPU).contiguous().clone(),
                         false);
  };
  std::ostringstream src;
  auto conv = [&](const Conv& c, const std::string& x, bool activate) {
    std::string e = c.replicate
                        ? "torch.conv2d(torch.replication_pad2d(" + x + ", [1, 1, 1, 1]), self." +
                              c.name + "_w, self." + c.name + "_b, [1, 1], [0, 0])"
                        : "torch.conv2d(" + x + ", self." + c.name + "_w, self." + c.name +
                              "_b, [1, 1], [1, 1])";
    std::ostringstream slope;
    slope.precision(9);
    slope << double(cfg_.leaky_slope);
    return activate ? "torch.leaky_relu(" + e + ", " + slope.str() + ")" : e;
  };
  src << "def forward(self, x: Tensor";
  if (cfg_.recurrent)
    for (int i = 0; i < kLevels; ++i) src << ", s" << i << ": Tensor";
  src << ")";
  if (cfg_.recurrent) {
    src << " -> Tuple[Tensor";
    for (int i = 0; i < kLevels; ++i) src << ", Tensor";
    src << "]";
  }
  // Any size: pad like pad_to_multiple() (edge replication), crop the output.
  src << ":\n  H = x.size(2)\n  W = x.size(3)\n"
      << "  ph = (" << kSizeMultiple << " - H % " << kSizeMultiple << ") % " << kSizeMultiple << "\n"
      << "  pw = (" << kSizeMultiple << " - W % " << kSizeMultiple << ") % " << kSizeMultiple << "\n"
      << "  if ph + pw > 0:\n    x = torch.replication_pad2d(x, [0, pw, 0, ph])\n"
      << "  h = x\n";
  for (int i = 0; i < kLevels; ++i) {
    if (cfg_.recurrent) src << "  h = torch.cat([h, s" << i << "], 1)\n";
    for (const Conv& c : enc_[i]) {
      reg(c);
      src << "  h = " << conv(c, "h", true) << "\n";
    }
    src << "  k" << i << " = h\n  h = torch.max_pool2d(h, [2, 2])\n";
  }
  for (const Conv& c : mid_) {
    reg(c);
    src << "  h = " << conv(c, "h", true) << "\n";
  }
  for (int i = kLevels - 1; i >= 0; --i) {
    src << "  h = torch.cat([torch.upsample_nearest2d(h, [h.size(2) * 2, h.size(3) * 2]), k" << i
        << "], 1)\n";
    for (const Conv& c : dec_[i]) {
      reg(c);
      src << "  h = " << conv(c, "h", c.activate) << "\n";
    }
  }
  if (out_.conv) {
    reg(out_);
    src << "  y = " << conv(out_, "h", false) << "\n";
  } else {
    src << "  y = h\n";
  }
  src << "  y = y[:, :, 0:H, 0:W]\n";
  if (cfg_.recurrent) {
    src << "  return (y";
    for (int i = 0; i < kLevels; ++i) src << ", k" << i;
    src << ")\n";
  } else {
    src << "  return y\n";
  }
  m.define(src.str());
  torch::jit::ExtraFilesMap extra(extra_files.begin(), extra_files.end());
  m.save(path.string(), extra);
}

torch::MemoryFormat preferred_memory_format(torch::Device device) {
  return device.is_cpu() ? torch::MemoryFormat::ChannelsLast : torch::MemoryFormat::Contiguous;
}

torch::Tensor pad_to_multiple(const torch::Tensor& x) {
  const int64_t h = x.size(-2), w = x.size(-1);
  const int64_t ph = (kSizeMultiple - h % kSizeMultiple) % kSizeMultiple;
  const int64_t pw = (kSizeMultiple - w % kSizeMultiple) % kSizeMultiple;
  if (ph == 0 && pw == 0) return x;
  namespace F = torch::nn::functional;
  // Replication keeps the padded border statistically like the image edge.
  return F::pad(x, F::PadFuncOptions({0, pw, 0, ph}).mode(torch::kReplicate));
}

int64_t parameter_count(const torch::nn::Module& m) {
  int64_t n = 0;
  for (const auto& p : m.parameters()) n += p.numel();
  return n;
}

}  // namespace dofarm::trainer
