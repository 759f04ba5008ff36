#include "worker/render/texture.h"

#include <cmath>

namespace dofarm::render {

namespace {

// Bilinear weights and texel indices at uv (glTF convention): texel centres
// sit at (i + 0.5) / size, so a texture of one texel is constant. Repeat
// blends the two border texels at uv 0 and 1; clamp holds the border
// texel beyond the outer centres; mirror reflects uv at every integer (so
// its borders hold too). Nearest (glTF magFilter NEAREST) takes the texel
// uv lies in: weights 0.
struct Bilinear {
  int x0, x1, y0, y1;
  float fx, fy;
  Bilinear(Vec2 uv, int width, int height, const TextureSampler& s = {}) {
    auto axis = [&s](float t, int size, TextureWrap wrap, int* i0, int* i1, float* frac) {
      if (!std::isfinite(t)) t = 0.0f;
      if (wrap == TextureWrap::kRepeat) [[likely]] {
        t -= std::floor(t);  // into [0, 1) first, so huge uvs keep their precision
      } else {
        if (wrap == TextureWrap::kMirror) {
          t -= 2.0f * std::floor(0.5f * t);  // [0, 2)
          if (t > 1.0f) t = 2.0f - t;
        }
        t = clamp01(t);
      }
      if (s.nearest) {
        const int i = static_cast<int>(t * static_cast<float>(size));
        *i0 = *i1 = i >= size ? size - 1 : i;
        *frac = 0.0f;
        return;
      }
      float x = t * static_cast<float>(size) - 0.5f;
      float fx = std::floor(x);
      *frac = x - fx;
      // t is in [0, 1], so i is in [-1, size - 1]: the wrap is one compare
      // each way (no integer division in the hot path).
      int i = static_cast<int>(fx);
      if (wrap == TextureWrap::kRepeat) [[likely]] {
        *i0 = i < 0 ? size - 1 : (i >= size ? size - 1 : i);
        *i1 = *i0 + 1 == size ? 0 : *i0 + 1;
      } else {
        *i0 = i < 0 ? 0 : (i >= size ? size - 1 : i);
        *i1 = i + 1 >= size ? size - 1 : (i + 1 < 0 ? 0 : i + 1);
      }
    };
    axis(uv.x, width, s.wrap_u, &x0, &x1, &fx);
    axis(uv.y, height, s.wrap_v, &y0, &y1, &fy);  // v = 0 is row 0, the top row (glTF)
  }
};

}  // namespace

float Texture::alpha_lookup(Vec2 uv) const {
  if (alpha.empty() || width <= 0 || height <= 0) return 1.0f;
  const Bilinear b(uv, width, height, sampler);
  auto at = [&](int x, int y) { return alpha[static_cast<size_t>(y) * width + x]; };
  auto mix = [](float p, float q, float t) { return p * (1.0f - t) + q * t; };
  return mix(mix(at(b.x0, b.y0), at(b.x1, b.y0), b.fx), mix(at(b.x0, b.y1), at(b.x1, b.y1), b.fx),
             b.fy);
}

Vec3 Texture::lookup(Vec2 uv) const {
  if (width <= 0 || height <= 0) return Vec3(1.0f);
  const Bilinear b(uv, width, height, sampler);
  auto texel = [&](int x, int y) {
    const float* p = &rgb[(static_cast<size_t>(y) * width + x) * 3];
    return Vec3(p[0], p[1], p[2]);
  };
  return lerp(lerp(texel(b.x0, b.y0), texel(b.x1, b.y0), b.fx),
              lerp(texel(b.x0, b.y1), texel(b.x1, b.y1), b.fx), b.fy);
}

// glTF KHR_texture_transform.
UvTransform UvTransform::from_gltf(Vec2 offset, float rotation, Vec2 scale) {
  // KHR_texture_transform: translation * rotation * scale, with the rotation
  // matrix of the extension's specification (rows (cos, sin), (-sin, cos)).
  const float c = std::cos(rotation), s = std::sin(rotation);
  UvTransform t;
  t.m[0] = c * scale.x;
  t.m[1] = s * scale.y;
  t.m[2] = offset.x;
  t.m[3] = -s * scale.x;
  t.m[4] = c * scale.y;
  t.m[5] = offset.y;
  return t;
}

}  // namespace dofarm::render
