// A scene as plain data, in world space, before Embree sees it: triangles,
// materials, textures and (optionally) a camera animation. Loaded from glTF
// 2.0 / OBJ / FBX by load_scene_data() through assimp, or built in code by the
// shape helpers (tests, analytic scenes).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "common/jobspec.h"
#include "common/math.h"
#include "worker/render/texture.h"

namespace dofarm::render {

// The largest radiance (emission of a material, in the renderer's radiance
// units) and radiant intensity or irradiance (punctual lights) a scene may
// hold. Larger or non-finite values are load errors: 1e12 is far beyond any
// physical source at scene scale (the sun's disc is ~2e7 W/(m^2 sr)), and
// keeping values this far below float's 3.4e38 leaves the room that path
// throughput, pixel sums and variances need to stay finite.
// The one definition lives beside the job spec, which bounds environment
// colours with it too.
using dofarm::kMaxRadiance;

// Watts per lumen at 555 nm: glTF gives light intensities in candela and lux;
// Blender's glTF exporter (io_scene_gltf2, PBR_WATTS_TO_LUMENS) multiplies
// its watts by 683 to write them, so dividing gives back Blender's radiometric
// units, which are the renderer's.
inline constexpr float kLumensPerWatt = 683.0f;

// glTF metallic-roughness material (what a glTF material maps onto exactly).
struct Material {
  std::string name;
  Vec3 base_color{0.8f};
  float metallic = 0.0f;
  float roughness = 0.5f;
  Vec3 emission{0.0f};  // radiance emitted (already times emissive strength)
  float ior = 1.5f;
  // KHR_materials_specular: the strength of the dielectric's specular layer
  // and the colour its F0 is multiplied by (worker/render/bsdf.h); 1 and
  // white without the extension.
  float specular = 1.0f;
  Vec3 specular_color{1.0f};
  // KHR_materials_transmission: the share of the dielectric that is a glass
  // interface refracting into the mesh (worker/render/bsdf.h).
  float transmission = 0.0f;
  // KHR_materials_volume: the absorption coefficient sigma_a = -ln(c) / d
  // per channel (attenuationColor c, attenuationDistance d) of the medium
  // a transmissive mesh encloses; 0 = clear.
  Vec3 attenuation{0.0f};
  // KHR_materials_clearcoat: the coat's strength and roughness (bsdf.h).
  float clearcoat = 0.0f;
  float clearcoat_roughness = 0.0f;
  // KHR_materials_sheen: the sheen's colour (black = none) and roughness (bsdf.h).
  Vec3 sheen_color{0.0f};
  float sheen_roughness = 0.0f;
  // The texture slots, each a texture and how it reads texture coordinates
  // (TextureSlot):
  TextureSlot base_color_tex;   // multiplies base_color
  TextureSlot metal_rough_tex;  // glTF: G = roughness, B = metallic; multiplies the factors
  TextureSlot emission_tex;     // multiplies emission
  // KHR_materials_transmission's and KHR_materials_clearcoat's textures
  // (linear): R multiplies transmission, R clearcoat, G clearcoat_roughness.
  TextureSlot transmission_tex, clearcoat_tex, clearcoat_rough_tex;
  // KHR_materials_sheen's: RGB (sRGB) multiplies sheen_color, A sheen_roughness.
  TextureSlot sheen_color_tex, sheen_rough_tex;
  // KHR_materials_specular's: A multiplies specular, RGB (sRGB) specular_color.
  TextureSlot specular_tex, specular_color_tex;
  // glTF normalTexture (tangent space, linear RGB; SceneData::tangents) and
  // its scale, which multiplies the map's x and y (glTF 3.9.3).
  TextureSlot normal_tex;
  float normal_scale = 1.0f;
  // KHR_materials_clearcoat's clearcoatNormalTexture and its scale: the
  // coat's own normal map (without it the coat is not normal-mapped, even
  // where the base is).
  TextureSlot clearcoat_normal_tex;
  float clearcoat_normal_scale = 1.0f;
  // glTF alphaMode MASK: a surface point whose alpha (baseColorFactor's
  // alpha times the base colour texture's) is below alpha_cutoff is not
  // there for any ray (an Embree filter, worker/render/scene.cpp). BLEND
  // (alpha_blend): a ray stops at the point with probability alpha, so the
  // surface covers that share of what is behind it, on average.
  bool alpha_mask = false;
  bool alpha_blend = false;
  float alpha_cutoff = 0.5f;
  float base_alpha = 1.0f;
  // Every slot, for what holds for all of them.
  std::array<const TextureSlot*, 12> slots() const {
    return {&base_color_tex,   &metal_rough_tex,      &emission_tex,        &normal_tex,
            &transmission_tex, &clearcoat_tex,        &clearcoat_rough_tex, &sheen_color_tex,
            &sheen_rough_tex,  &clearcoat_normal_tex, &specular_tex,        &specular_color_tex};
  }
  bool is_emissive() const { return emission.x > 0 || emission.y > 0 || emission.z > 0; }
  // Whether some texture slot reads TEXCOORD_1.
  bool reads_uv1() const {
    for (const TextureSlot* t : slots())
      if (t->present() && t->uv.set == 1) return true;
    return false;
  }
  bool has_normal_map() const { return normal_tex.present() || clearcoat_normal_tex.present(); }
  // The set the material's normal maps read (the base's, else the coat's).
  uint8_t normal_map_set() const {
    return normal_tex.present() ? normal_tex.uv.set : clearcoat_normal_tex.uv.set;
  }
  bool has_textures() const {
    for (const TextureSlot* t : slots())
      if (t->present()) return true;
    return false;
  }
};

struct CameraTrackKey {
  float time = 0;  // seconds
  Vec3 position;
  Quat rotation;  // camera looks down its -z
  float yfov_deg = 40;
  // Width over height of the camera's film as the file gives it (glTF
  // camera.perspective.aspectRatio, or xmag / ymag); 0 when the file does
  // not say.
  float aspect = 0;
  // An orthographic camera (glTF camera.orthographic): half the height of
  // its film in scene units (ymag); 0 for a perspective camera.
  float ymag = 0;
};

// A KHR_lights_punctual light, in world space and the renderer's units.
// Without a size, a delta light that only next-event estimation reaches;
// with one (radius, cos_half_angle), an area light that BSDF samples reach
// as well (Scene::lamps_along).
struct PunctualLight {
  enum class Type { kPoint, kSpot, kDirectional };
  Type type = Type::kPoint;
  std::string name;
  Vec3 position{0.0f};       // point, spot
  Vec3 direction{0, 0, -1};  // spot, directional: where the light travels (unit)
  // Point, spot: radiant intensity (radiance units x m^2 per sr), so the
  // irradiance at distance d facing the light is intensity / d^2.
  // Directional: the irradiance on a surface facing it.
  Vec3 intensity{0.0f};
  float cos_inner = 1.0f, cos_outer = -1.0f;  // spot cone: full inside inner, 0 outside outer
  // A lamp's size, which glTF does not carry (JobSpec::light_radius,
  // sun_angle_deg): point and spot, the radius of a disk facing the lit
  // point; directional, the cosine of half the angular diameter. 0 and 1:
  // a point, parallel light (a delta light).
  float radius = 0.0f;
  float cos_half_angle = 1.0f;
  // A spot from a file Blender wrote: its Spot Blend, recovered from the
  // cones (the exporter writes inner = outer (1 - blend)), and the spot
  // attenuates as Cycles 3.4 attenuates it (cycles_spot_attenuation). < 0:
  // the extension's recommended falloff (spot_falloff).
  float blender_spot_blend = -1.0f;
};

// KHR_lights_punctual's spot falloff, the smooth one the extension's
// specification recommends: (clamp((cos - cos_outer) / (cos_inner - cos_outer)))^2,
// the denominator kept above 1e-3.
float spot_falloff(float cos_angle, float cos_inner, float cos_outer);

// How Cycles 3.4 attenuates a Blender Spot of half angle theta_s (cosine
// `cos_half_spot`) and Spot Blend b at an angle whose cosine is c from its
// axis: 0 outside the cone; inside, c itself, times smoothstep(t / s) where
// t = c - cos theta_s is below s = (1 - cos theta_s) b (Cycles'
// spot_attenuation: its light falls off with the cosine to the axis too).
float cycles_spot_attenuation(float cos_angle, float cos_half_spot, float blend);

// A spot's attenuation towards a direction at cosine `cos_angle` from its
// axis: Cycles' for a Blender spot, else the extension's.
inline float spot_attenuation(const PunctualLight& spot, float cos_angle) {
  return spot.blender_spot_blend >= 0
             ? cycles_spot_attenuation(cos_angle, spot.cos_outer, spot.blender_spot_blend)
             : spot_falloff(cos_angle, spot.cos_inner, spot.cos_outer);
}

struct SceneMotion;  // worker/render/scene_motion.h
struct SceneCamera;  // worker/render/scene_motion.h

struct SceneData {
  std::filesystem::path source;  // file it came from (empty if built in code)
  std::string generator;         // a glTF's asset.generator (what wrote the file)
  std::vector<Vec3> positions;
  // Per vertex; empty = use geometric normals. Unit length, except that a
  // zero normal means "use the geometric normal" for that vertex (add_mesh
  // writes zeros when meshes with and without normals are mixed).
  std::vector<Vec3> normals;
  std::vector<Vec2> uvs;               // per vertex; empty = no texture coordinates
  // TEXCOORD_1 per vertex, for textures whose UvTransform::set is 1; empty
  // unless a material reads it (then as long as `positions`; a mesh without
  // the set repeats its TEXCOORD_0 here).
  std::vector<Vec2> uvs1;
  // Per vertex, for normal maps: the tangent along +u, orthogonal to the
  // vertex normal, and the sign w that makes cross(n, t) w point along the
  // image's up (glTF's TANGENT convention; v grows downwards in glTF, so up
  // is -dp/dv). Empty unless a material has a normal map
  // (compute_tangents()).
  struct Tangent {
    Vec3 t;
    float w = 1.0f;
  };
  std::vector<Tangent> tangents;
  std::vector<uint32_t> indices;       // 3 per triangle
  std::vector<uint32_t> tri_material;  // one per triangle
  std::vector<Material> materials;
  std::vector<Texture> textures;
  // The file's camera at its keys' times (the union over its node and the
  // node's parents); empty = no camera in the file. camera_for_frame()
  // takes each frame's pose from scene_camera, exactly at the frame's time,
  // where the loader sets it (always, with a track); the track serves
  // SceneData built in code.
  std::vector<CameraTrackKey> camera_track;
  std::shared_ptr<const SceneCamera> scene_camera;
  // Why the file's camera cannot be used, where it has one that dofarm
  // does not render; camera_track is then empty.
  std::string camera_refused;
  // Every camera of the file, in the order assimp lists them; the scene
  // camera is the one load_scene_data() was asked for, else the first.
  std::vector<std::string> camera_names;
  std::vector<PunctualLight> lights;         // glTF KHR_lights_punctual
  // Meshes and lights that the file's node animation moves; null when
  // nothing but the camera moves. The arrays above then hold the nodes'
  // own transforms (from Blender: the frame the file was exported at), and
  // a frame is rendered from pose() at its time (Scene::at_time).
  std::shared_ptr<const SceneMotion> motion;

  size_t triangle_count() const { return tri_material.size(); }
  // Appends a mesh with its own material; returns the material index. `n` and
  // `uv` are empty or one per vertex of `p`; indices refer to `p`. Where
  // `uvs1` is in use, the mesh's TEXCOORD_1 is its `uv`.
  uint32_t add_mesh(const std::vector<Vec3>& p, const std::vector<Vec3>& n,
                    const std::vector<Vec2>& uv, const std::vector<uint32_t>& idx,
                    const Material& m);
};

// Whether Blender's glTF exporter wrote the file: it puts its name into
// asset.generator ("Khronos glTF Blender I/O vX.Y.Z").
inline bool written_by_blender(const SceneData& scene) {
  return scene.generator.find("Blender") != std::string::npos;
}

// Loads a glTF 2.0 (.gltf/.glb), OBJ or FBX file, flattening the node
// hierarchy into world space. Throws SpecError (file name, reason) when the
// file is missing, unreadable, has no triangles, has a non-finite vertex, a
// material whose emission is non-finite or above kMaxRadiance, a texture that
// cannot be loaded, or (glTF) lists in extensionsRequired an extension dofarm
// does not implement. Extensions in extensionsUsed that dofarm does not
// implement are named in one warning. Points and lines are ignored;
// degenerate triangles are kept. Textures embedded in the file (.glb buffer
// views, data: URIs) are decoded from memory. glTF coverage and units:
// docs/renderer.md, "glTF coverage". KHR_materials_emissive_strength and
// KHR_texture_transform are read from the file's JSON (assimp 5.2 drops the
// first and converts the second into its own convention); lights come
// through assimp's aiLight. Node animation moves the camera
// (camera_track), and meshes, skinned meshes and lights (motion); morph
// targets are named in a warning and not applied.
// `camera`: the name of the camera to take as the scene camera (a job's
// camera.name); empty takes the file's first. A name the file does not have
// leaves camera_track empty and says so in camera_refused.
SceneData load_scene_data(const std::filesystem::path& path, const std::string& camera = {});

// Fills data->tangents from positions, normals and uvs (uvs1 for triangles
// whose material's normal map reads TEXCOORD_1): per triangle the
// derivatives dp/du and -dp/dv (Lengyel 2001, "Computing Tangent Space Basis
// Vectors for an Arbitrary Mesh"), as unit vectors weighted by the
// triangle's area and summed at its vertices, then per vertex made orthogonal to the normal
// (Gram-Schmidt) and unit, with w the handedness. A vertex whose triangles
// have no uv extent gets some unit vector orthogonal to its normal. Needs
// uvs; MikkTSpace, which glTF recommends, agrees on planar and regular meshes
// and differs on irregular ones in how vertices average their triangles.
void compute_tangents(SceneData* data);

}  // namespace dofarm::render
