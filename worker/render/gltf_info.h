// What the scene loader (scene_data.cpp) reads of a glTF file's JSON beyond
// what assimp 5.2 gives it, what the material extensions among it do to a
// material, and the check of the file's extension lists.
#pragma once

#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "worker/render/scene_data.h"

namespace dofarm::render {

// What dofarm reads of a glTF beyond what assimp 5.2.5 gives: per material,
// KHR_materials_emissive_strength (assimp drops it silently) and each
// texture's KHR_texture_transform (assimp converts it into its own
// aiUVTransform convention; the file's numbers are taken as the extension
// defines them instead); the file's extension lists.
struct GltfTextureInfo {
  bool present = false;  // the material names this texture
  int index = -1;        // into the file's textures (GltfInfo::textures)
  UvTransform transform;
  int tex_coord = 0;  // TEXCOORD_n the texture reads (texCoord, or the transform's override)
};
// A glTF texture's image and sampler, for textures assimp 5.2 does not hand
// out itself (KHR_materials_specular's): a file beside the scene (its uri
// as `name`), or an image held in the file (a buffer view or a data: URI:
// `held`, `name` "image <index>", read by read_gltf_image(); assimp names
// only the embedded images its own materials use, so its "*k" cannot be
// relied on); `name` empty where the texture has no image.
struct GltfTextureRef {
  std::string name;
  int image = -1;
  bool held = false;
  TextureSampler sampler;
};
struct GltfMaterialInfo {
  std::string name;  // to check that assimp kept the order
  float emissive_strength = 1.0f;
  GltfTextureInfo base_color, metal_rough, emission, normal;
  float normal_scale = 1.0f;  // normalTexture.scale
  // alphaMode: MASK (cut out below alpha_cutoff) or BLEND (a ray stops with
  // probability alpha); base_alpha is baseColorFactor's alpha.
  bool mask = false, blend = false;
  float alpha_cutoff = 0.5f, base_alpha = 1.0f;
  // KHR_materials_ior: present = the extension is there (its "ior" or the
  // extension's default 1.5); ior < 1 or non-finite is outside the schema.
  bool ior_present = false;
  double ior = 1.5;
  // KHR_materials_specular's factors as written (NaN: not a number, or the
  // wrong shape) and textures (specularTexture A, specularColorTexture RGB,
  // sRGB).
  double specular_factor = 1.0;
  double specular_color[3] = {1.0, 1.0, 1.0};
  GltfTextureInfo specular_tex, specular_color_tex;
  // KHR_materials_transmission's factor as written (0 without the
  // extension; NaN: not a number) and its texture (R).
  double transmission = 0.0;
  GltfTextureInfo transmission_tex;
  // KHR_materials_volume's attenuation as written (distance +inf and
  // colour white without the extension; NaN: not a number or the wrong
  // shape); thickness is a rasteriser's stand-in for the geometry, which
  // a ray tracer has.
  double attenuation_distance = INFINITY;
  double attenuation_color[3] = {1.0, 1.0, 1.0};
  // KHR_materials_clearcoat's factors as written (0 without it; NaN: not a
  // number) and their textures (clearcoatTexture R, clearcoatRoughnessTexture
  // G, clearcoatNormalTexture: the coat's own normal map).
  double clearcoat = 0.0, clearcoat_roughness = 0.0;
  GltfTextureInfo clearcoat_tex, clearcoat_rough_tex, clearcoat_normal_tex;
  float clearcoat_normal_scale = 1.0f;  // clearcoatNormalTexture.scale
  // KHR_materials_sheen's factors as written (black and 0 without it; NaN:
  // not a number or the wrong shape) and their textures (sheenColorTexture
  // RGB, sRGB; sheenRoughnessTexture A).
  double sheen_color[3] = {0.0, 0.0, 0.0};
  double sheen_roughness = 0.0;
  GltfTextureInfo sheen_color_tex, sheen_rough_tex;
};
struct GltfInfo {
  std::vector<GltfMaterialInfo> materials;
  std::vector<GltfTextureRef> textures;  // the file's textures, in order
  std::vector<std::string> extensions_used, extensions_required;
  bool vertex_colors = false;  // a primitive has COLOR_0 (not applied)
  // Meshes (their names, else "mesh N") with a primitive that names no
  // material: glTF gives those its default material.
  std::vector<std::string> meshes_without_material;
  // Every animation channel that targets a named node's translation,
  // rotation or scale: the animation's index, the node's name, the path and
  // the sampler's interpolation ("LINEAR", "STEP" or "CUBICSPLINE"; assimp
  // 5.2 hands out the keys of all three alike, and fills each channel's
  // other paths with the node's static value).
  struct AnimatedPath {
    size_t animation = 0;
    std::string node, path, interpolation;
    // CUBICSPLINE: the sampler's output, per key its in-tangent, value and
    // out-tangent (3 x 3 or 3 x 4 floats); empty otherwise, or where it
    // cannot be read (named in a warning).
    std::vector<float> cubic;
  };
  std::vector<AnimatedPath> animated_paths;
  // Every node that holds a camera: its name ("" when it has none) and the
  // camera's clipping planes (znear, zfar; zfar infinite when the file
  // gives none, as glTF 3.10.2 defines for a perspective camera); for an
  // orthographic one also xmag and ymag, half its film's width and height
  // (NaN where the file gives no number).
  struct CameraNode {
    std::string node;
    double znear = 0.0, zfar = std::numeric_limits<double>::infinity();
    bool orthographic = false;
    double xmag = std::numeric_limits<double>::quiet_NaN();
    double ymag = std::numeric_limits<double>::quiet_NaN();
  };
  std::vector<CameraNode> camera_nodes;
  std::string generator;  // asset.generator ("" when the file gives none)
};

// The JSON of a .gltf, or of a .glb's JSON chunk; empty where the file is
// not JSON (assimp then gives the reason).
GltfInfo read_gltf_info(const std::filesystem::path& path);

// The encoded bytes (PNG, JPEG, ...) of image `image` held in the glTF file
// `path`: a data: URI, or a buffer view of the .glb's binary chunk or of a
// buffer given by a data: URI or a file beside the scene. Throws
// RuntimeError naming the image and what is wrong (out of range, not
// base64, a view beyond its buffer).
std::string read_gltf_image(const std::filesystem::path& path, int image);

// What the extensions read above do to material `index`: KHR_materials_
// specular, _transmission, _volume, _clearcoat and _sheen's factors, checked
// against their schemas; a value outside is named in a warning (file,
// material, key) and the extension's default used. Their textures are the
// loader's (scene_data.cpp).
void apply_material_extensions(const std::filesystem::path& path, const GltfMaterialInfo& g,
                               unsigned index, Material* m);

// glTF 3.12: a required extension the loader does not implement means the
// asset cannot be rendered correctly, so it is refused (SpecError naming
// the file); one that is only used is named in one warning, so nothing is
// dropped silently; so are vertex colours, which are not applied.
void check_extensions(const std::filesystem::path& path, const GltfInfo& info);

}  // namespace dofarm::render
