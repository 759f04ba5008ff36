#include "common/image.h"

#include <cmath>
#include <cstring>

#include "common/error.h"

namespace dofarm {

const std::vector<BufferInfo>& buffer_infos() {
  static const std::vector<BufferInfo> infos = {
      {"noisy", 3, true},      {"albedo", 3, true},         {"albedo_ref", 3, false},
      {"reference", 3, false}, {"reference_var", 1, false}, {"normal", 3, false},
      {"depth", 1, false},     {"roughness", 1, false},     {"coc", 1, false},
      {"reference_half", 3, false},
  };
  return infos;
}

std::vector<float>& buffer_data(FrameBuffers& fb, const std::string& name) {
  if (name == "noisy") return fb.noisy;
  if (name == "albedo") return fb.albedo;
  if (name == "albedo_ref") return fb.albedo_ref;
  if (name == "reference") return fb.reference;
  if (name == "reference_var") return fb.reference_var;
  if (name == "normal") return fb.normal;
  if (name == "depth") return fb.depth;
  if (name == "roughness") return fb.roughness;
  if (name == "coc") return fb.coc;
  if (name == "reference_half") return fb.reference_half;
  throw RuntimeError("unknown buffer name '" + name + "'");
}

const std::vector<float>& buffer_data(const FrameBuffers& fb, const std::string& name) {
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
