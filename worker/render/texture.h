// Image textures as the renderer reads them: texels, the glTF sampler
// (filter and wrap) and KHR_texture_transform. Loaded by load_scene_data()
// (scene_data.h), looked up at every textured hit (scene.cpp).
#pragma once

#include <cstdint>
#include <string>
#include <tuple>
#include <vector>

#include "common/math.h"

namespace dofarm::render {

// Linear RGB texture; 8-bit colour data is converted from sRGB on load.
// How a texture is read between and beyond its texels: glTF's sampler
// (magFilter NEAREST = Blender's "Closest" interpolation; wrapS / wrapT
// CLAMP_TO_EDGE = "Extend", MIRRORED_REPEAT = "Mirror"). The default is
// bilinear and repeating in both directions.
enum class TextureWrap : uint8_t { kRepeat, kClamp, kMirror };
struct TextureSampler {
  bool nearest = false;
  TextureWrap wrap_u = TextureWrap::kRepeat, wrap_v = TextureWrap::kRepeat;
  bool operator<(const TextureSampler& o) const {
    return std::tie(nearest, wrap_u, wrap_v) < std::tie(o.nearest, o.wrap_u, o.wrap_v);
  }
};

struct Texture {
  int width = 0, height = 0;
  std::vector<float> rgb;  // interleaved, row 0 = top (v = 0 in glTF)
  // Per texel in [0, 1]; empty = opaque. Loaded only for the base colour
  // texture of a material with alphaMode MASK or BLEND.
  std::vector<float> alpha;
  std::string name;
  TextureSampler sampler;
  // Filtered and wrapped as `sampler` says; uv in glTF convention.
  Vec3 lookup(Vec2 uv) const;
  float alpha_lookup(Vec2 uv) const;  // the same filter over `alpha`; 1 without
};

// How a texture slot reads texture coordinates: from the set TEXCOORD_`set`
// (glTF textureInfo.texCoord, or KHR_texture_transform's override; dofarm
// reads sets 0 and 1), then KHR_texture_transform as a 2x3 affine map of
// glTF texture coordinates: uv' = offset + R(rotation) * (scale * uv), with
// R as the extension defines it (u' = cos u + sin v, v' = -sin u + cos v
// before the offset).
struct UvTransform {
  float m[6] = {1, 0, 0, 0, 1, 0};  // u' = m0 u + m1 v + m2, v' = m3 u + m4 v + m5
  uint8_t set = 0;                  // TEXCOORD_0 or TEXCOORD_1
  static UvTransform from_gltf(Vec2 offset, float rotation, Vec2 scale);
  Vec2 apply(Vec2 uv) const {
    return {m[0] * uv.x + m[1] * uv.y + m[2], m[3] * uv.x + m[4] * uv.y + m[5]};
  }
  bool is_identity() const {
    return m[0] == 1 && m[1] == 0 && m[2] == 0 && m[3] == 0 && m[4] == 1 && m[5] == 0;
  }
};

// A material's texture slot: which texture (an index into
// SceneData::textures, -1 for none) and how the slot reads texture
// coordinates.
struct TextureSlot {
  int index = -1;
  UvTransform uv;
  bool present() const { return index >= 0; }
};

}  // namespace dofarm::render
