// Frame EXRs (docs/exr_format.md) and the plain RGB EXRs of reports and of
// other renderers' frames. The bytes are read and written by
// common/exr_stream.cpp; image loading is common/image_load.cpp.
#include "common/exr_io.h"

#include <ImfBoxAttribute.h>
#include <ImfChannelList.h>
#include <ImfDoubleAttribute.h>
#include <ImfFloatAttribute.h>
#include <ImfFloatVectorAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfIntAttribute.h>
#include <ImfStringAttribute.h>
#include <ImfVecAttribute.h>

#include <algorithm>
#include <cmath>
#include <exception>

#include "common/checksum.h"
#include "common/error.h"
#include "common/exr_stream.h"

namespace dofarm {
namespace {

using exr_detail::MemIStream;
using exr_detail::quoted;
using exr_detail::read_whole_file;
using exr_detail::write_exr_atomically;

// Written into every frame EXR; read_frame_exr() refuses any other value, so a
// future layout change cannot be misread silently (STYLE.md 9). Version 1
// (tiles at 0,0 with dofarm.rect; no root layer) is still read: staged tiles
// of a batch begun before an upgrade stay valid.
constexpr const char* kFrameSchema = "dofarm.frame/2";
constexpr const char* kFrameSchemaV1 = "dofarm.frame/1";
constexpr const char* kSchemaAttr = "dofarm.schema";
constexpr const char* kRgbAttr = "dofarm.rgb";
constexpr const char* kRectAttr = "dofarm.rect";  // version 1 only
constexpr const char* kVersionsAttr = "dofarm.versions";
constexpr const char* kFrameAttr = "dofarm.camera.frame";
constexpr const char* kTimeAttr = "dofarm.camera.time";
constexpr const char* kPositionAttr = "dofarm.camera.position";
constexpr const char* kRotationAttr = "dofarm.camera.rotation";
constexpr const char* kFovAttr = "dofarm.camera.fov";
constexpr const char* kFocalDistanceAttr = "dofarm.camera.focal_distance";
constexpr const char* kApertureAttr = "dofarm.camera.aperture";
// Only in the header of an orthographic camera's frame (absent: perspective),
// so a perspective frame's file is what it was before orthographic cameras.
constexpr const char* kOrthoHeightAttr = "dofarm.camera.ortho_height";

// What the root R, G, B hold (dofarm.rgb).
constexpr const char* kRgbReference = "reference";
constexpr const char* kRgbNoisyMean = "noisy_mean";

// String attributes OpenEXR itself defines for multi-part and multi-view
// files; they are never user attributes.
bool is_openexr_string_attribute(const std::string& name) {
  return name == "name" || name == "type" || name == "view";
}

// --- Channel layout (docs/exr_format.md) --------------------------------------

// One EXR channel and the plane of FrameBuffers it maps to.
struct ChannelPlane {
  std::string name;
  const char* buffer;
  size_t plane;  // index of the H*W plane inside the buffer
};

// Channel suffixes of a named layer. Version 2: colours R/G/B, scalars Y
// (what viewers show as grey), and the normal R/G/B as well, as Arnold and
// Nuke store N: OpenImageIO takes the first channel whose last name part is
// Z or Depth as the depth channel (and A or Alpha as alpha), so no layer but
// the root Z may end in ".Z". Version 1 wrote the normal as X/Y/Z.
const char* channel_suffix(const BufferInfo& b, int c, int schema) {
  static const char* const kColour[] = {"R", "G", "B"};
  static const char* const kVector[] = {"X", "Y", "Z"};
  if (b.channels == 1) return "Y";
  return schema == 1 && std::string(b.name) == "normal" ? kVector[c] : kColour[c];
}

// Every channel of a frame with `versions` noisy versions, in schema order.
// Version 2: the reference is the root R, G, B and the depth the root Z;
// the rest are named layers noisy.<v>.R/G/B, albedo.<v>.R/G/B,
// albedo_ref.R/G/B, reference_var.Y, normal.R/G/B, roughness.Y, coc.Y.
// `with_reference` false leaves out the reference and its variance (a frame
// without a reference: the root R, G, B then hold the noisy mean, which is
// no buffer). Version 1 named every buffer as a layer (reference.R,
// depth.Y, normal.X/Y/Z).
std::vector<ChannelPlane> channel_planes(int versions, int schema, bool with_reference = true) {
  static const char* const kRoot[] = {"R", "G", "B"};
  std::vector<ChannelPlane> out;
  for (const BufferInfo& b : buffer_infos()) {
    const std::string name = b.name;
    if (!with_reference && (name == "reference" || name == "reference_var" || name == "reference_half")) continue;
    if (schema == 2 && name == "reference") {
      for (int c = 0; c < 3; ++c) out.push_back({kRoot[c], b.name, size_t(c)});
      continue;
    }
    if (schema == 2 && name == "depth") {
      out.push_back({"Z", b.name, 0});
      continue;
    }
    const int layers = b.per_version ? versions : 1;
    for (int v = 0; v < layers; ++v) {
      const std::string layer = b.per_version ? name + "." + std::to_string(v) : name;
      for (int c = 0; c < b.channels; ++c)
        out.push_back(
            {layer + "." + channel_suffix(b, c, schema), b.name, size_t(v) * b.channels + c});
    }
  }
  return out;
}

}  // namespace

std::string frame_exr_channel(const std::string& buffer, int c, const std::string& version) {
  for (const ChannelPlane& p : channel_planes(1, 2)) {
    const BufferInfo& b = buffer_info(buffer);
    if (p.buffer != buffer || p.plane != size_t(c)) continue;
    if (!b.per_version) return p.name;
    return buffer + "." + version + p.name.substr(buffer.size() + 2);  // past "NAME.0"
  }
  throw RuntimeError("frame EXRs have no channel " + std::to_string(c) + " of '" + buffer + "'");
}

namespace {

// --- Frame header -----------------------------------------------------------

template <typename T>
const T& required_attribute(const Imf::Header& header, const char* name,
                            const std::filesystem::path& path) {
  const T* attr = header.findTypedAttribute<T>(name);
  if (!attr)
    throw RuntimeError(quoted(path) + ": missing or mistyped header attribute '" + name +
                       "' (not a dofarm frame EXR?)");
  return *attr;
}

void write_camera(Imf::Header& header, const CameraState& cam) {
  header.insert(kFrameAttr, Imf::IntAttribute(cam.frame));
  header.insert(kTimeAttr, Imf::FloatAttribute(cam.time));
  header.insert(kPositionAttr,
                Imf::V3fAttribute(Imath::V3f(cam.position[0], cam.position[1], cam.position[2])));
  // Imath has no quaternion attribute; a float vector keeps w, x, y, z exact.
  header.insert(kRotationAttr,
                Imf::FloatVectorAttribute(std::vector<float>(cam.rotation, cam.rotation + 4)));
  header.insert(kFovAttr, Imf::FloatAttribute(cam.fov_deg));
  header.insert(kFocalDistanceAttr, Imf::FloatAttribute(cam.focal_distance));
  header.insert(kApertureAttr, Imf::FloatAttribute(cam.aperture));
  if (cam.orthographic()) header.insert(kOrthoHeightAttr, Imf::FloatAttribute(cam.ortho_height));
}

CameraState read_camera(const Imf::Header& header, const std::filesystem::path& path) {
  CameraState cam;
  cam.frame = required_attribute<Imf::IntAttribute>(header, kFrameAttr, path).value();
  cam.time = required_attribute<Imf::FloatAttribute>(header, kTimeAttr, path).value();
  const Imath::V3f& p = required_attribute<Imf::V3fAttribute>(header, kPositionAttr, path).value();
  cam.position[0] = p.x;
  cam.position[1] = p.y;
  cam.position[2] = p.z;
  const std::vector<float>& q =
      required_attribute<Imf::FloatVectorAttribute>(header, kRotationAttr, path).value();
  if (q.size() != 4)
    throw RuntimeError(quoted(path) + ": '" + kRotationAttr + "' has " + std::to_string(q.size()) +
                       " values, expected 4 (w, x, y, z)");
  std::copy(q.begin(), q.end(), cam.rotation);
  cam.fov_deg = required_attribute<Imf::FloatAttribute>(header, kFovAttr, path).value();
  cam.focal_distance =
      required_attribute<Imf::FloatAttribute>(header, kFocalDistanceAttr, path).value();
  cam.aperture = required_attribute<Imf::FloatAttribute>(header, kApertureAttr, path).value();
  if (header.find(kOrthoHeightAttr) != header.end())
    cam.ortho_height =
        required_attribute<Imf::FloatAttribute>(header, kOrthoHeightAttr, path).value();
  return cam;
}
}  // namespace

uint64_t write_frame_exr(const std::filesystem::path& path, const FrameBuffers& fb,
                         const std::map<std::string, std::string>& attributes, FrameExtent frame) {
  if (fb.width <= 0 || fb.height <= 0 || fb.versions < 0)
    throw RuntimeError("cannot write EXR " + quoted(path) + ": empty frame (" +
                       std::to_string(fb.width) + "x" + std::to_string(fb.height) + ", " +
                       std::to_string(fb.versions) + " versions)");
  // A frame without a reference has neither the reference nor its variance.
  const bool with_reference = !fb.reference.empty();
  // Buffer sizes disagreeing with width/height/versions is a programmer
  // error; checking here keeps OpenEXR from reading past a vector's end.
  for (const BufferInfo& b : buffer_infos()) {
    const std::string name = b.name;
    const bool absent = !with_reference && (name == "reference" || name == "reference_var" || name == "reference_half");
    DOFARM_CHECK_EQ(
        buffer_data(fb, b.name).size(),
        absent ? 0 : size_t(b.channels) * fb.plane() * (b.per_version ? fb.versions : 1));
  }
  // The root R, G, B need something to show.
  DOFARM_CHECK(with_reference || fb.versions > 0);
  // The data window is the rect, inside a display window of the whole frame.
  // An empty rect (buffers filled by hand) is the whole image.
  const Rect rect = fb.rect == Rect{} ? Rect{0, 0, fb.width, fb.height} : fb.rect;
  if (frame.width <= 0) frame.width = rect.x + fb.width;
  if (frame.height <= 0) frame.height = rect.y + fb.height;
  DOFARM_CHECK_EQ(rect.w, fb.width);
  DOFARM_CHECK_EQ(rect.h, fb.height);
  DOFARM_CHECK_GE(rect.x, 0);
  DOFARM_CHECK_GE(rect.y, 0);
  DOFARM_CHECK_LE(rect.x + fb.width, frame.width);
  DOFARM_CHECK_LE(rect.y + fb.height, frame.height);
  // Nothing non-finite is ever written (DESIGN.md: no NaN or Inf reaches a
  // buffer); name every offending buffer so the bug can be found.
  std::string bad;
  for (const BufferInfo& b : buffer_infos()) {
    size_t n = 0;
    for (float v : buffer_data(fb, b.name)) n += !std::isfinite(v);
    if (n) bad += std::string(bad.empty() ? "" : ", ") + b.name + " has " + std::to_string(n);
  }
  if (!bad.empty())
    throw RuntimeError("refusing to write EXR " + quoted(path) + ": NaN/Inf values (" + bad + ")");

  const Imath::Box2i display(Imath::V2i(0, 0), Imath::V2i(frame.width - 1, frame.height - 1));
  const Imath::Box2i data(Imath::V2i(rect.x, rect.y),
                          Imath::V2i(rect.x + fb.width - 1, rect.y + fb.height - 1));
  Imf::Header header(display, data);
  header.compression() = Imf::ZIP_COMPRESSION;
  header.insert(kSchemaAttr, Imf::StringAttribute(kFrameSchema));
  header.insert(kRgbAttr, Imf::StringAttribute(with_reference ? kRgbReference : kRgbNoisyMean));
  header.insert(kVersionsAttr, Imf::IntAttribute(fb.versions));
  write_camera(header, fb.camera);
  for (const auto& [key, value] : attributes) {
    if (key.empty() || header.find(key) != header.end() || is_openexr_string_attribute(key) ||
        key == kRectAttr)
      throw RuntimeError("cannot write EXR " + quoted(path) + ": attribute name '" + key +
                         "' is empty or reserved");
    header.insert(key, Imf::StringAttribute(value));
  }

  Imf::FrameBuffer frame_buffer;
  const size_t plane = fb.plane();
  const size_t row = sizeof(float) * size_t(fb.width);
  // Slices address the data window: OpenEXR adds (x, y) * strides to the base.
  auto insert = [&](const std::string& name, const float* base) {
    header.channels().insert(name, Imf::Channel(Imf::FLOAT));
    // OpenEXR only reads through the slice pointer when writing.
    frame_buffer.insert(
        name, Imf::Slice::Make(Imf::FLOAT, const_cast<float*>(base), data, sizeof(float), row));
  };
  for (const ChannelPlane& ch : channel_planes(fb.versions, 2, with_reference))
    insert(ch.name, buffer_data(fb, ch.buffer).data() + ch.plane * plane);
  // Without a reference the root R, G, B show the mean of the noisy versions
  // (dofarm.rgb says so); the reader does not take it for a buffer.
  std::vector<float> mean;
  if (!with_reference) {
    mean.assign(3 * plane, 0.0f);
    for (int v = 0; v < fb.versions; ++v)
      for (size_t i = 0; i < 3 * plane; ++i) mean[i] += fb.noisy[size_t(v) * 3 * plane + i];
    for (float& m : mean) m /= float(fb.versions);
    static const char* const kRoot[] = {"R", "G", "B"};
    for (int c = 0; c < 3; ++c) insert(kRoot[c], mean.data() + size_t(c) * plane);
  }
  // Opaque: every pixel is covered (by geometry or the environment). With A
  // present, tools that keep four channels (oiiotool to PNG) keep R, G, B, A
  // instead of taking Z for alpha.
  const std::vector<float> alpha(plane, 1.0f);
  insert("A", alpha.data());
  return write_exr_atomically(path, header, frame_buffer);
}

ExrFrame read_frame_exr(const std::filesystem::path& path, uint64_t* file_checksum) {
  ExrFrame out;
  try {
    // One read: the same bytes are checksummed and decoded.
    const std::vector<char> bytes = read_whole_file(path);
    if (file_checksum) *file_checksum = checksum64(bytes.data(), bytes.size());
    MemIStream stream(path.string(), bytes);
    Imf::InputFile file(stream);
    const Imf::Header& header = file.header();
    const std::string schema_name =
        required_attribute<Imf::StringAttribute>(header, kSchemaAttr, path).value();
    if (schema_name != kFrameSchema && schema_name != kFrameSchemaV1)
      throw RuntimeError(quoted(path) + ": unknown schema '" + schema_name +
                         "', this build reads '" + kFrameSchema + "' and '" + kFrameSchemaV1 + "'");
    const int schema = schema_name == kFrameSchema ? 2 : 1;
    // A truncated file still has an intact header; refuse it before reading
    // rather than returning zero-filled pixels.
    if (!file.isComplete()) throw RuntimeError(quoted(path) + ": file is incomplete (truncated?)");

    const Imath::Box2i dw = header.dataWindow();
    const Imath::Box2i disp = header.displayWindow();
    const int versions = required_attribute<Imf::IntAttribute>(header, kVersionsAttr, path).value();
    if (versions < 0)
      throw RuntimeError(quoted(path) + ": negative '" + kVersionsAttr + "' " +
                         std::to_string(versions));
    FrameBuffers& fb = out.buffers;
    fb.allocate(dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1, versions);
    bool with_reference = true;
    if (schema == 1) {
      const Imath::Box2i r =
          required_attribute<Imf::Box2iAttribute>(header, kRectAttr, path).value();
      fb.rect = {r.min.x, r.min.y, r.max.x - r.min.x + 1, r.max.y - r.min.y + 1};
      if (fb.rect.w != fb.width || fb.rect.h != fb.height)
        throw RuntimeError(quoted(path) + ": '" + kRectAttr + "' disagrees with the image size");
      out.frame = {fb.rect.x + fb.width, fb.rect.y + fb.height};
    } else {
      // The tile sits where its data window is, inside the frame's display
      // window whose origin is 0,0.
      if (disp.min.x != 0 || disp.min.y != 0 || dw.min.x < 0 || dw.min.y < 0 ||
          dw.max.x > disp.max.x || dw.max.y > disp.max.y)
        throw RuntimeError(quoted(path) + ": data window is not inside a display window at 0,0");
      fb.rect = {dw.min.x, dw.min.y, fb.width, fb.height};
      out.frame = {disp.max.x + 1, disp.max.y + 1};
      const std::string rgb =
          required_attribute<Imf::StringAttribute>(header, kRgbAttr, path).value();
      if (rgb != kRgbReference && rgb != kRgbNoisyMean)
        throw RuntimeError(quoted(path) + ": unknown '" + kRgbAttr + "' value '" + rgb + "'");
      with_reference = rgb == kRgbReference;
    }
    if (!with_reference) {
      fb.reference.clear();
      fb.reference_var.clear();
      fb.reference_half.clear();
    }
    fb.camera = read_camera(header, path);

    Imf::FrameBuffer frame_buffer;
    const size_t plane = fb.plane();
    std::string missing;
    for (const ChannelPlane& ch : channel_planes(versions, schema, with_reference)) {
      if (!header.channels().findChannel(ch.name)) {
        missing += (missing.empty() ? "" : ", ") + ch.name;
        continue;
      }
      float* base = buffer_data(fb, ch.buffer).data() + ch.plane * plane;
      frame_buffer.insert(ch.name, Imf::Slice::Make(Imf::FLOAT, base, dw, sizeof(float),
                                                    sizeof(float) * size_t(fb.width)));
    }
    if (!missing.empty()) throw RuntimeError(quoted(path) + ": missing channels " + missing);
    file.setFrameBuffer(frame_buffer);
    file.readPixels(dw.min.y, dw.max.y);

    for (auto it = header.begin(); it != header.end(); ++it) {
      const std::string name = it.name();
      if (name == kSchemaAttr || name == kRgbAttr || is_openexr_string_attribute(name)) continue;
      if (const auto* s = dynamic_cast<const Imf::StringAttribute*>(&it.attribute()))
        out.attributes[name] = s->value();
    }
  } catch (const RuntimeError&) {
    throw;
  } catch (const std::exception& e) {
    throw RuntimeError("cannot read EXR " + quoted(path) + ": " + e.what());
  }
  return out;
}

void write_rgb_exr(const std::filesystem::path& path, const RgbImage& img) {
  if (img.width <= 0 || img.height <= 0)
    throw RuntimeError("cannot write EXR " + quoted(path) + ": empty image");
  DOFARM_CHECK_EQ(img.rgb.size(), size_t(img.width) * img.height * 3);
  // Non-finite values are written as they are: this is for looking at
  // images, and a debug image should show a NaN rather than hide it.
  Imf::Header header(img.width, img.height);
  header.compression() = Imf::ZIP_COMPRESSION;
  Imf::FrameBuffer frame_buffer;
  const char* const names[] = {"R", "G", "B"};
  for (int c = 0; c < 3; ++c) {
    header.channels().insert(names[c], Imf::Channel(Imf::FLOAT));
    float* base = const_cast<float*>(img.rgb.data()) + c;
    frame_buffer.insert(names[c],
                        Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(base), 3 * sizeof(float),
                                   3 * sizeof(float) * size_t(img.width)));
  }
  write_exr_atomically(path, header, frame_buffer);
}

ExrImage read_exr_image(const std::filesystem::path& path) {
  ExrImage img;
  try {
    // InputFile reads scanline and tiled single-part files alike.
    Imf::InputFile file(path.c_str());
    const Imf::Header& header = file.header();
    if (!file.isComplete()) throw RuntimeError("file is incomplete (truncated?)");
    const Imath::Box2i dw = header.dataWindow();
    const Imath::Box2i disp = header.displayWindow();
    img.width = dw.max.x - dw.min.x + 1;
    img.height = dw.max.y - dw.min.y + 1;
    img.data_window = {dw.min.x, dw.min.y, img.width, img.height};
    img.display = {disp.max.x - disp.min.x + 1, disp.max.y - disp.min.y + 1};
    const size_t plane = size_t(img.width) * img.height;
    Imf::FrameBuffer frame_buffer;
    for (auto it = header.channels().begin(); it != header.channels().end(); ++it) {
      if (it.channel().xSampling != 1 || it.channel().ySampling != 1)
        throw RuntimeError(std::string("channel '") + it.name() + "' is subsampled");
      std::vector<float>& data = img.channels[it.name()];
      data.assign(plane, 0.0f);
      frame_buffer.insert(it.name(), Imf::Slice::Make(Imf::FLOAT, data.data(), dw, sizeof(float),
                                                      sizeof(float) * size_t(img.width)));
    }
    file.setFrameBuffer(frame_buffer);
    file.readPixels(dw.min.y, dw.max.y);
    for (auto it = header.begin(); it != header.end(); ++it) {
      const Imf::Attribute& a = it.attribute();
      if (const auto* s = dynamic_cast<const Imf::StringAttribute*>(&a))
        img.strings[it.name()] = s->value();
      else if (const auto* f = dynamic_cast<const Imf::FloatAttribute*>(&a))
        img.numbers[it.name()] = f->value();
      else if (const auto* d = dynamic_cast<const Imf::DoubleAttribute*>(&a))
        img.numbers[it.name()] = d->value();
      else if (const auto* i = dynamic_cast<const Imf::IntAttribute*>(&a))
        img.numbers[it.name()] = i->value();
    }
  } catch (const std::exception& e) {
    throw RuntimeError("cannot read EXR " + quoted(path) + ": " + e.what());
  }
  return img;
}

void write_rgb_exr_like(const std::filesystem::path& path, const RgbImage& img,
                        const std::vector<float>& alpha, const std::filesystem::path& like,
                        const std::map<std::string, std::string>& attributes) {
  if (img.width <= 0 || img.height <= 0)
    throw RuntimeError("cannot write EXR " + quoted(path) + ": empty image");
  DOFARM_CHECK_EQ(img.rgb.size(), size_t(img.width) * img.height * 3);
  DOFARM_CHECK(alpha.empty() || alpha.size() == size_t(img.width) * img.height);
  size_t bad = 0;
  for (float v : img.rgb) bad += !std::isfinite(v);
  for (float v : alpha) bad += !std::isfinite(v);
  if (bad)
    throw RuntimeError("refusing to write EXR " + quoted(path) + ": " + std::to_string(bad) +
                       " NaN/Inf values");
  Imf::Header source;
  try {
    source = Imf::InputFile(like.c_str()).header();
  } catch (const std::exception& e) {
    throw RuntimeError("cannot read EXR " + quoted(like) + ": " + e.what());
  }
  // The picture's windows when they fit this image; a plain 0,0 image else.
  const Imath::Box2i sdw = source.dataWindow();
  const bool same_size =
      sdw.max.x - sdw.min.x + 1 == img.width && sdw.max.y - sdw.min.y + 1 == img.height;
  const Imath::Box2i data =
      same_size ? sdw : Imath::Box2i(Imath::V2i(0, 0), Imath::V2i(img.width - 1, img.height - 1));
  Imf::Header header(same_size ? source.displayWindow() : data, data);
  header.compression() = Imf::ZIP_COMPRESSION;
  // Attributes that describe the layout of `like`, not the picture: they
  // would be false of this file (its schema, its channel groups).
  static const char* const kLayout[] = {
      "channels",           "compression", "dataWindow",  "displayWindow",
      "lineOrder",          "type",        "name",        "version",
      "chunkCount",         "tiles",       "view",        "multiView",
      kSchemaAttr,          kRgbAttr,      kVersionsAttr, kRectAttr,
      "BlenderMultiChannel"};
  for (auto it = source.begin(); it != source.end(); ++it) {
    const std::string name = it.name();
    if (std::find(std::begin(kLayout), std::end(kLayout), name) != std::end(kLayout)) continue;
    header.insert(name, it.attribute());
  }
  for (const auto& [key, value] : attributes) {
    if (key.empty() || std::find(std::begin(kLayout), std::end(kLayout), key) != std::end(kLayout))
      throw RuntimeError("cannot write EXR " + quoted(path) + ": attribute name '" + key +
                         "' is empty or reserved");
    header.erase(key);
    header.insert(key, Imf::StringAttribute(value));
  }
  Imf::FrameBuffer frame_buffer;
  const char* const names[] = {"R", "G", "B"};
  const size_t row = sizeof(float) * size_t(img.width);
  for (int c = 0; c < 3; ++c) {
    header.channels().insert(names[c], Imf::Channel(Imf::FLOAT));
    frame_buffer.insert(names[c],
                        Imf::Slice::Make(Imf::FLOAT, const_cast<float*>(img.rgb.data()) + c, data,
                                         3 * sizeof(float), 3 * row));
  }
  if (!alpha.empty()) {
    header.channels().insert("A", Imf::Channel(Imf::FLOAT));
    frame_buffer.insert("A", Imf::Slice::Make(Imf::FLOAT, const_cast<float*>(alpha.data()), data,
                                              sizeof(float), row));
  }
  write_exr_atomically(path, header, frame_buffer);
}

}  // namespace dofarm
