// The node hierarchy of a scene file: meshes placed by their nodes, the
// camera track, node animation (SceneMotion) and KHR_lights_punctual lights.
#include <assimp/anim.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <set>

#include "worker/render/foreign_cameras.h"
#include "worker/render/scene_loader.h"

namespace dofarm::render::detail {

void Loader::node(const aiNode* node, const aiMatrix4x4& parent) {
  const aiMatrix4x4 world = parent * node->mTransformation;
  // A skinned mesh moves with its joints, whatever its node does, and a
  // mesh whose morph weights an animation drives changes shape.
  bool deforms = false;
  double tps;
  unsigned animation;
  for (unsigned k = 0; k < node->mNumMeshes; ++k) {
    const aiMesh* m = scene_->mMeshes[node->mMeshes[k]];
    deforms = deforms || m->HasBones() ||
              (m->mNumAnimMeshes > 0 && morph_channel(node->mName.C_Str(), &tps, &animation));
  }
  const int moving = node->mNumMeshes > 0 && (moves(node) || deforms) ? int(motion_node(node)) : -1;
  for (unsigned k = 0; k < node->mNumMeshes; ++k) {
    mesh(scene_->mMeshes[node->mMeshes[k]], world, node->mName.C_Str(), moving);
  }
  for (unsigned c = 0; c < node->mNumChildren; ++c) this->node(node->mChildren[c], world);
}

// --- camera animation --------------------------------------------------------

void Loader::camera_track(const std::string& wanted) {
  if (scene_->mNumCameras == 0) return;
  // The scene's camera: the one asked for by name, else the first; others
  // are ignored.
  const aiCamera* cam = nullptr;
  for (unsigned i = 0; i < scene_->mNumCameras; ++i) {
    out_->camera_names.push_back(scene_->mCameras[i]->mName.C_Str());
    if (!cam && (wanted.empty() || out_->camera_names.back() == wanted)) cam = scene_->mCameras[i];
  }
  if (!cam) {
    out_->camera_refused = fmt::format("it has no camera named \"{}\" (its cameras: {})", wanted,
                                       quoted_list(out_->camera_names));
    return;
  }
  const aiNode* cam_node = scene_->mRootNode->FindNode(cam->mName);
  if (!cam_node) return;
  const bool gltf = is_gltf(path_);
  // Its entry in the file's JSON: the camera node of the same name, or the
  // file's only camera node (clipping planes, and an orthographic camera's
  // size; assimp 5.2 puts 100 in place of a zfar the file leaves out, which
  // glTF reads as infinite, and gives an orthographic camera only xmag).
  const GltfInfo::CameraNode* json = nullptr;
  for (const GltfInfo::CameraNode& c : gltf_.camera_nodes)
    if (c.node == cam->mName.C_Str()) json = &c;
  if (!json && gltf_.camera_nodes.size() == 1) json = &gltf_.camera_nodes.front();
  // An orthographic camera (glTF camera.orthographic, Blender's Orthographic
  // type): assimp gives it no field of view; its film is 2 xmag by 2 ymag
  // scene units (glTF 3.10.3). Read from a glTF file's JSON; from another
  // format (or with a size glTF forbids) a job that takes it is refused
  // (camera_for_frame(), complete_spec_from_scene()): rendered with a field
  // of view of 0 it would show one point of the scene in every pixel.
  float ymag = 0, ortho_aspect = 0;
  // Collada and FBX: assimp reads an orthographic camera of theirs as a
  // perspective one (foreign_cameras.h), so the file itself says which it
  // is. Collada's is rendered from its <orthographic> size. Blender's FBX
  // holds the Orthographic Scale as OrthoZoom, in Blender units, spanning
  // the film's longer side (sensor fit auto, as the glTF exporter's xmag
  // and ymag say), and is rendered from it: each camera is found by its
  // Model's name in the file's records (binary, which Blender writes, or
  // ASCII), or, where they cannot be read, only when it is the file's only
  // camera. Other FBX files' OrthoZoom has no
  // agreed unit, and a camera the scan cannot match to assimp's is unknown:
  // those are refused.
  const std::string ext = lower_extension(path_);
  const ForeignCameras foreign = ext == ".dae"   ? scan_collada_cameras(file_bytes())
                                 : ext == ".fbx" ? scan_fbx_cameras(file_bytes())
                                                 : ForeignCameras{};
  auto usable = [](double x, double y) {
    return x > 0 && y > 0 && x < 1e30 && y < 1e30 && x / y < 1e6 && y / x < 1e6;
  };
  if (foreign.any_orthographic()) {
    const std::string name = cam->mName.C_Str();
    const ForeignCamera* own = foreign.find(name);
    const bool collada = foreign.format == ForeignCameras::Format::kCollada;
    const bool named_fbx = !collada && own && !own->name.empty();
    const double zoom = named_fbx ? own->ortho_zoom : foreign.fbx_ortho_zoom;
    const double film = cam->mAspect > 0 && std::isfinite(cam->mAspect) ? cam->mAspect : 1.0;
    const double half_long = 0.5 * zoom;
    const double fbx_x = film >= 1 ? half_long : half_long * film;
    const double fbx_y = film >= 1 ? half_long / film : half_long;
    if ((collada || named_fbx) && own && !own->orthographic) {
      // A perspective camera in a file that also has orthographic ones.
    } else if (collada && own && usable(own->xmag, own->ymag)) {
      ymag = float(own->ymag);
      ortho_aspect = float(own->xmag / own->ymag);
    } else if (!collada && from_blender() &&
               (named_fbx || (scene_->mNumCameras == 1 && foreign.cameras.size() == 1)) &&
               usable(fbx_x, fbx_y)) {
      ymag = float(fbx_y);
      ortho_aspect = float(fbx_x / fbx_y);
    } else {
      const size_t n = foreign.cameras.size();
      out_->camera_refused =
          collada && own ? fmt::format(
                               "its camera \"{}\" is orthographic without a size (Collada "
                               "<orthographic> needs two of xmag, ymag and aspect_ratio)",
                               name)
          : collada ? fmt::format(
                          "it has orthographic cameras, and which of its cameras is \"{}\" "
                          "cannot be told; export the scene as glTF",
                          name)
          : named_fbx || scene_->mNumCameras == 1
              ? fmt::format(
                    "its camera \"{}\" is orthographic (FBX CameraProjectionType 1) with "
                    "OrthoZoom {:g}, which only Blender's FBX files give a unit; export the "
                    "scene as glTF (or Collada) to render it",
                    name, zoom)
              : fmt::format(
                    "{} of its {} cameras {} orthographic (FBX CameraProjectionType 1), "
                    "which assimp reads as perspective cameras without saying which; "
                    "export the scene as glTF (or Collada) to render it",
                    n, scene_->mNumCameras, n == 1 ? "is" : "are");
      return;
    }
  } else if (!(cam->mHorizontalFOV > 0) || !std::isfinite(cam->mHorizontalFOV)) {
    const std::string name = cam->mName.C_Str();
    const bool ortho = gltf && json && json->orthographic;
    const double x = ortho ? std::fabs(json->xmag) : 0.0, y = ortho ? std::fabs(json->ymag) : 0.0;
    if (ortho && x > 0 && y > 0 && x < 1e30 && y < 1e30 && x / y < 1e6 && y / x < 1e6) {
      ymag = float(y);
      ortho_aspect = float(x / y);
    } else {
      out_->camera_refused =
          ortho ? fmt::format(
                      "its camera \"{}\" is orthographic with xmag {:g} and ymag {:g}, and glTF "
                      "requires both to be non-zero numbers",
                      name, json->xmag, json->ymag)
          : cam->mOrthographicWidth > 0
              ? fmt::format(
                    "its camera \"{}\" is orthographic (half width {:g}); dofarm renders "
                    "orthographic cameras from glTF files only",
                    name, cam->mOrthographicWidth)
              : fmt::format("its camera \"{}\" has no field of view", name);
      return;
    }
  }
  // The camera on its node, posed by the node hierarchy's samplers at any
  // time (SceneCamera; camera_for_frame() asks it at each frame's time),
  // and as a track of its poses at the key times on its chain (root ...
  // camera node), each node's keys as for meshes (SceneMotion).
  const uint32_t cam_index = motion_node(cam_node);
  std::set<float> times;
  auto add_times = [&times](const auto& track) {
    for (float t : track.times) times.insert(t);
  };
  for (int n = int(cam_index); n >= 0; n = motion_->nodes[size_t(n)].parent) {
    const MotionNode& node = motion_->nodes[size_t(n)];
    add_times(node.translation_keys);
    add_times(node.rotation_keys);
    add_times(node.scale_keys);
  }
  if (times.empty()) times.insert(0.0f);  // a static camera: one key

  // A glTF camera sits at its node's origin looking down -z with +y up
  // (glTF 2.0, 3.10.1). assimp 5.2.5 also copies the node's translation into
  // aiCamera::mPosition, which would apply it twice, so for glTF the camera's
  // own frame is taken from the spec rather than from aiCamera.
  auto camera = std::make_shared<SceneCamera>();
  camera->motion = motion_;
  camera->node = cam_index;
  camera->name = cam->mName.C_Str();
  camera->position = gltf ? Vec3(0.0f) : to_vec3(cam->mPosition);
  camera->back = gltf ? Vec3(0, 0, 1) : -normalize(to_vec3(cam->mLookAt), Vec3(0, 0, -1));
  camera->up = gltf ? Vec3(0, 1, 0) : normalize(to_vec3(cam->mUp), Vec3(0, 1, 0));
  // assimp's glTF2 importer stores mHorizontalFOV = yfov * aspect (checked
  // against a file with yfov 0.8, aspect 2: it reports 1.6), so dividing
  // recovers glTF's yfov exactly. Other importers store the full horizontal
  // angle, which converts through the tangents.
  if (ymag > 0) {
    camera->yfov_deg = 0;
    camera->ymag = ymag;
    camera->aspect = ortho_aspect;
  } else {
    const float aspect = cam->mAspect > 0 ? cam->mAspect : 1.0f;
    const float yfov = gltf ? cam->mHorizontalFOV / aspect
                            : 2.0f * std::atan(std::tan(cam->mHorizontalFOV * 0.5f) / aspect);
    camera->yfov_deg = yfov * 180.0f / kPi;
    camera->aspect = cam->mAspect > 0 ? cam->mAspect : 0.0f;
  }
  // Its clipping planes: from a glTF file's JSON; for an orthographic
  // Collada or FBX camera from assimp (its lens sits on the near plane, as
  // below). Other formats' perspective cameras are not clipped.
  if (!gltf && ymag > 0) {
    // FBX's planes are in the file's unit (UnitScaleFactor centimetres),
    // which aiProcess_GlobalScale applies to nodes and meshes, not to them.
    float unit = 1.0f;
    if (foreign.format == ForeignCameras::Format::kFbx) {
      float cm = 1.0f;
      if (scene_->mMetaData && scene_->mMetaData->Get("UnitScaleFactor", cm) && std::isfinite(cm) &&
          cm > 0)
        unit = cm / 100.0f;
      else
        unit = 0.01f;
    }
    const float znear = cam->mClipPlaneNear * unit, zfar = cam->mClipPlaneFar * unit;
    if (std::isfinite(znear) && znear > 0) camera->znear = znear;
    if (std::isfinite(zfar) && zfar > camera->znear && zfar < 1e30f) camera->zfar = zfar;
  }
  if (const GltfInfo::CameraNode* clip = json) {
    if (std::isfinite(clip->znear) && clip->znear > 0 && clip->znear < 1e30) {
      camera->znear = float(clip->znear);
    } else if (!(ymag > 0 && clip->znear == 0)) {  // glTF allows an orthographic znear of 0
      spdlog::warn(
          "{}: camera \"{}\" has znear {:g}, which glTF requires to be positive; not "
          "clipped near",
          path_.string(), camera->name, clip->znear);
    }
    if (clip->zfar > camera->znear && clip->zfar < 1e30) {
      camera->zfar = float(clip->zfar);
    } else if (!std::isinf(clip->zfar)) {
      spdlog::warn("{}: camera \"{}\" has zfar {:g}, not beyond its znear {:g}; not clipped far",
                   path_.string(), camera->name, clip->zfar, camera->znear);
    }
  }
  for (float t : times) {
    const CameraTrackKey key = camera->at(t);
    if (!is_finite(key.position) || !std::isfinite(key.yfov_deg)) {
      fail(path_, "camera \"" + camera->name + "\" has a non-finite transform");
    }
    out_->camera_track.push_back(key);
  }
  out_->scene_camera = std::move(camera);
}

// --- node animation (meshes and lights) ---------------------------------------

void Loader::animation_channels() {
  for (unsigned a = 0; a < scene_->mNumAnimations; ++a) {
    const aiAnimation* anim = scene_->mAnimations[a];
    const double tps = anim->mTicksPerSecond > 0 ? anim->mTicksPerSecond : 1.0;
    for (unsigned c = 0; c < anim->mNumChannels; ++c)
      channels_.emplace(anim->mChannels[c]->mNodeName.C_Str(), Channel{anim->mChannels[c], tps});
  }
}

namespace {

// assimp's keys (ticks) as a track in seconds. assimp 5.2 gives every key
// of a glTF sampler as a value (of a CUBICSPLINE sampler: the spline's
// points, without their tangents).
template <typename Key, typename T, typename Convert>
void read_keys(const Key* keys, unsigned count, double ticks_per_second, Track<T>* track,
               Convert convert) {
  for (unsigned i = 0; i < count; ++i) {
    track->times.push_back(float(keys[i].mTime / ticks_per_second));
    track->values.push_back(convert(keys[i].mValue));
  }
}

}  // namespace

uint32_t Loader::motion_node(const aiNode* n) {
  if (auto it = motion_index_.find(n); it != motion_index_.end()) return it->second;
  MotionNode node;
  node.parent = n->mParent ? int(motion_node(n->mParent)) : -1;
  node.fixed = to_affine(n->mTransformation);
  const std::string name = n->mName.C_Str();
  if (auto it = channels_.find(name); it != channels_.end()) {
    // glTF: an animated node has translation, rotation and scale, not a
    // matrix (3.11), so the decomposition is exact.
    aiVector3D s, t;
    aiQuaternion r;
    n->mTransformation.Decompose(s, r, t);
    node.translation = to_vec3(t);
    node.scale = to_vec3(s);
    node.rotation = Quat{r.w, r.x, r.y, r.z};
    auto vec = [](const aiVector3D& v) { return to_vec3(v); };
    double tps = 1;
    bool step = false;
    const std::vector<float>* cubic = nullptr;
    // A CUBICSPLINE sampler's tangents from the file's JSON: per key `width`
    // floats of in-tangent, value, out-tangent (glTF quaternions x, y, z, w).
    auto tangents = [&](auto* track, size_t width, auto make) {
      const size_t keys = track->times.size();
      if (!cubic) return;
      if (cubic->size() != 3 * width * keys) {
        spdlog::warn(
            "{}: the CUBICSPLINE {} of node \"{}\" has {} floats for {} keys; its keys "
            "are interpolated linearly",
            path_.string(), width == 4 ? "rotation" : "translation or scale", name, cubic->size(),
            keys);
        return;
      }
      for (size_t k = 0; k < keys; ++k) {
        track->in_tangents.push_back(make(&(*cubic)[3 * width * k]));
        track->out_tangents.push_back(make(&(*cubic)[3 * width * k + 2 * width]));
      }
    };
    auto vec3_at = [](const float* f) { return Vec3(f[0], f[1], f[2]); };
    if (const aiNodeAnim* ch = path_channel(name, "translation", &tps, &step, &cubic)) {
      read_keys(ch->mPositionKeys, ch->mNumPositionKeys, tps, &node.translation_keys, vec);
      node.translation_keys.step = step;
      tangents(&node.translation_keys, 3, vec3_at);
    }
    if (const aiNodeAnim* ch = path_channel(name, "scale", &tps, &step, &cubic)) {
      read_keys(ch->mScalingKeys, ch->mNumScalingKeys, tps, &node.scale_keys, vec);
      node.scale_keys.step = step;
      tangents(&node.scale_keys, 3, vec3_at);
    }
    if (const aiNodeAnim* ch = path_channel(name, "rotation", &tps, &step, &cubic)) {
      read_keys(ch->mRotationKeys, ch->mNumRotationKeys, tps, &node.rotation_keys,
                [](const aiQuaternion& q) {
                  return Quat{q.w, q.x, q.y, q.z};
                });
      node.rotation_keys.step = step;
      tangents(&node.rotation_keys, 4, [](const float* f) { return Quat{f[3], f[0], f[1], f[2]}; });
    }
    // Keys as glTF requires them (3.11): finite values at increasing times;
    // rotations are made unit.
    const std::string bad = "the animation of node \"" + name + "\" has ";
    auto check_times = [&](const std::vector<float>& times) {
      for (size_t i = 0; i < times.size(); ++i)
        if (!std::isfinite(times[i]) || (i > 0 && !(times[i] > times[i - 1])))
          fail(path_, bad + "key times that are not finite and increasing");
    };
    for (const Track<Vec3>* track : {&node.translation_keys, &node.scale_keys}) {
      check_times(track->times);
      for (Vec3 v : track->values)
        if (!is_finite(v)) fail(path_, bad + "a non-finite key");
    }
    check_times(node.rotation_keys.times);
    for (Quat& q : node.rotation_keys.values) {
      const float len = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
      if (!std::isfinite(len) || !(len > 0))
        fail(path_, bad + "a rotation key that is not a rotation");
      q = Quat{q.w / len, q.x / len, q.y / len, q.z / len};
    }
  }
  motion_->nodes.push_back(std::move(node));
  const auto index = uint32_t(motion_->nodes.size() - 1);
  motion_index_.emplace(n, index);
  return index;
}

const aiNodeAnim* Loader::path_channel(const std::string& name, const char* path,
                                       double* ticks_per_second, bool* step,
                                       const std::vector<float>** cubic) const {
  *step = false;
  *cubic = nullptr;
  bool named = false;
  for (const GltfInfo::AnimatedPath& ap : gltf_.animated_paths) {
    if (ap.node != name) continue;
    named = true;
    if (ap.path != path || ap.animation >= scene_->mNumAnimations) continue;
    const aiAnimation* anim = scene_->mAnimations[ap.animation];
    for (unsigned c = 0; c < anim->mNumChannels; ++c) {
      if (anim->mChannels[c]->mNodeName.C_Str() != name) continue;
      *ticks_per_second = anim->mTicksPerSecond > 0 ? anim->mTicksPerSecond : 1.0;
      *step = ap.interpolation == "STEP";
      if (ap.interpolation == "CUBICSPLINE") *cubic = &ap.cubic;
      return anim->mChannels[c];
    }
  }
  if (named) return nullptr;  // the file's animations do not move this path
  const auto it = channels_.find(name);
  if (it == channels_.end()) return nullptr;
  *ticks_per_second = it->second.ticks_per_second;
  return it->second.keys;
}

const aiMeshMorphAnim* Loader::morph_channel(const char* node_name, double* ticks_per_second,
                                             unsigned* animation) const {
  for (unsigned a = 0; a < scene_->mNumAnimations; ++a) {
    const aiAnimation* anim = scene_->mAnimations[a];
    for (unsigned c = 0; c < anim->mNumMorphMeshChannels; ++c)
      if (std::strcmp(anim->mMorphMeshChannels[c]->mName.C_Str(), node_name) == 0 &&
          anim->mMorphMeshChannels[c]->mNumKeys > 0) {
        *ticks_per_second = anim->mTicksPerSecond > 0 ? anim->mTicksPerSecond : 1.0;
        *animation = a;
        return anim->mMorphMeshChannels[c];
      }
  }
  return nullptr;
}

const GltfInfo::AnimatedPath* Loader::weights_path(const char* node_name,
                                                   unsigned animation) const {
  for (const GltfInfo::AnimatedPath& ap : gltf_.animated_paths)
    if (ap.animation == animation && ap.path == "weights" && ap.node == node_name) return &ap;
  return nullptr;
}

// Node animation moves meshes, skins, morph targets and lights frame by
// frame (SceneMotion).
void Loader::finish_motion() {
  if (!motion_->parts.empty() || !motion_->lights.empty()) {
    if (!motion_->tangents.empty()) {
      motion_->tangents.resize(motion_->positions.size());
      motion_->bitangents.resize(motion_->positions.size());
    }
    out_->motion = motion_;
  }
  // Vertex animation by whole meshes (assimp's aiMeshAnim, from formats
  // such as MD2; glTF has none) is not followed.
  unsigned replaced = 0;
  for (unsigned a = 0; a < scene_->mNumAnimations; ++a)
    replaced += scene_->mAnimations[a]->mNumMeshChannels;
  if (replaced > 0)
    spdlog::warn("{}: {} mesh-replacement animation channel(s) ignored: meshes keep their shape",
                 path_.string(), replaced);
}

// --- lights --------------------------------------------------------------------

void Loader::lights() {
  if (scene_->mNumLights == 0) return;
  if (!is_gltf(path_)) {
    // Other formats' light units are the exporter's guess; only glTF's are defined.
    spdlog::warn("{}: {} light(s) ignored: dofarm reads lights from glTF files only",
                 path_.string(), scene_->mNumLights);
    return;
  }
  for (unsigned i = 0; i < scene_->mNumLights; ++i) {
    const aiLight* al = scene_->mLights[i];
    const std::string name = al->mName.C_Str();
    // assimp names a glTF light after the node that holds it.
    const aiNode* node = scene_->mRootNode->FindNode(al->mName);
    if (!node) {
      spdlog::warn("{}: light \"{}\" is on no node; ignored", path_.string(), name);
      continue;
    }
    aiMatrix4x4 world;  // at the nodes' own transforms; pose() moves an animated one
    for (const aiNode* n = node; n; n = n->mParent) world = n->mTransformation * world;
    PunctualLight light;
    light.name = name;
    light.position = to_vec3(world * al->mPosition);
    // glTF: spot and directional lights shine down their node's -z (assimp's
    // mDirection); the direction ignores the node's scale.
    light.direction = normalize(to_vec3(aiMatrix3x3(world) * al->mDirection), Vec3(0, 0, -1));
    // assimp hands out colour x intensity, in candela (point, spot) or lux
    // (directional); see kLumensPerWatt for the conversion.
    light.intensity =
        Vec3(al->mColorDiffuse.r, al->mColorDiffuse.g, al->mColorDiffuse.b) / kLumensPerWatt;
    switch (al->mType) {
      case aiLightSource_POINT:
        light.type = PunctualLight::Type::kPoint;
        break;
      case aiLightSource_SPOT:
        light.type = PunctualLight::Type::kSpot;
        light.cos_inner = std::cos(al->mAngleInnerCone);
        light.cos_outer = std::cos(al->mAngleOuterCone);
        // Blender's exporter writes its Spot Size and Blend as the cones
        // (outer = size / 2, inner = outer (1 - blend)); Cycles attenuates
        // by neither cone's KHR falloff (scene_data.h).
        if (written_by_blender(*out_) && al->mAngleOuterCone > 0)
          light.blender_spot_blend =
              std::clamp(1.0f - al->mAngleInnerCone / al->mAngleOuterCone, 0.0f, 1.0f);
        break;
      case aiLightSource_DIRECTIONAL:
        light.type = PunctualLight::Type::kDirectional;
        break;
      default:
        spdlog::warn("{}: light \"{}\" of assimp type {} ignored", path_.string(), name,
                     int(al->mType));
        continue;
    }
    const std::string which = "light " + std::to_string(i) + " (\"" + name + "\")";
    if (!is_finite(light.position) || !is_finite(light.intensity) ||
        !std::isfinite(light.cos_inner) || !std::isfinite(light.cos_outer))
      fail(path_, which + " has a non-finite value");
    if (light.intensity.x < 0 || light.intensity.y < 0 || light.intensity.z < 0)
      fail(path_, which + " has a negative intensity");
    if (max_component(light.intensity) > kMaxRadiance)
      fail(path_, which + " has intensity " + fmt::format("{:g}", max_component(light.intensity)) +
                      " (after dividing by 683 lm/W), above the bound kMaxRadiance = 1e12");
    if (moves(node)) {
      MovingLight moving;
      moving.light = uint32_t(out_->lights.size());
      moving.node = motion_node(node);
      moving.position = to_vec3(al->mPosition);
      moving.direction = to_vec3(al->mDirection);
      motion_->lights.push_back(moving);
    }
    out_->lights.push_back(std::move(light));
  }
}

}  // namespace dofarm::render::detail
