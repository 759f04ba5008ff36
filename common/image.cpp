#include "common/image.h"

#include <cmath>
#include <cstring>

#include "common/error.h"

namespace dofarm {

const std::vector<BufferInfo>& buffer_infos() {
  static const std::vector<BufferInfo> infos = {
      {"noisy", 3, true, "R,G,B", &FrameBuffers::noisy},
      {"albedo", 3, true, "R,G,B", &FrameBuffers::albedo},
      {"albedo_ref", 3, false, "R,G,B", &FrameBuffers::albedo_ref},
      {"reference", 3, false, "R,G,B", &FrameBuffers::reference},
      {"reference_var", 1, false, "Y", &FrameBuffers::reference_var},
      {"normal", 3, false, "X,Y,Z", &FrameBuffers::normal},
      {"depth", 1, false, "Y", &FrameBuffers::depth},
      {"roughness", 1, false, "Y", &FrameBuffers::roughness},
      {"coc", 1, false, "Y", &FrameBuffers::coc},
      {"reference_half", 3, false, "R,G,B", &FrameBuffers::reference_half, true},
  };
  return infos;
}

const BufferInfo& buffer_info(std::string_view name) {
  for (const BufferInfo& b : buffer_infos())
    if (name == b.name) return b;
  throw RuntimeError("unknown buffer name '" + std::string(name) + "'");
}

std::string channel_name(const BufferInfo& b, int c) {
  DOFARM_CHECK_LT(c, b.channels);
  const std::string names = b.channel_names;
  size_t begin = 0;
  for (int i = 0; i < c; ++i) begin = names.find(',', begin) + 1;
  return names.substr(begin, names.find(',', begin) - begin);
}

std::vector<float>& buffer_data(FrameBuffers& fb, std::string_view name) {
  return fb.*(buffer_info(name).data);
}

const std::vector<float>& buffer_data(const FrameBuffers& fb, std::string_view name) {
  return buffer_data(const_cast<FrameBuffers&>(fb), name);
}

void FrameBuffers::allocate(int w, int h, int v) {
  width = w;
  height = h;
  versions = v;
  for (const BufferInfo& b : buffer_infos()) {
    size_t n = size_t(b.channels) * w * h * (b.per_version ? v : 1);
    buffer_data(*this, b.name).assign(n, 0.0f);
  }
}

void FrameBuffers::paste(const FrameBuffers& t) {
  DOFARM_CHECK_EQ(t.versions, versions);
  DOFARM_CHECK_LE(t.rect.x + t.width, width);
  DOFARM_CHECK_LE(t.rect.y + t.height, height);
  for (const BufferInfo& b : buffer_infos()) {
    const std::vector<float>& src = buffer_data(t, b.name);
    std::vector<float>& dst = buffer_data(*this, b.name);
    int planes = b.channels * (b.per_version ? versions : 1);
    for (int p = 0; p < planes; ++p)
      for (int y = 0; y < t.height; ++y)
        std::memcpy(&dst[(size_t(p) * height + t.rect.y + y) * width + t.rect.x],
                    &src[(size_t(p) * t.height + y) * t.width], sizeof(float) * t.width);
  }
}

size_t FrameBuffers::count_non_finite() const {
  size_t n = 0;
  for (const BufferInfo& b : buffer_infos())
    for (float v : buffer_data(*this, b.name)) n += !std::isfinite(v);
  return n;
}

}  // namespace dofarm
