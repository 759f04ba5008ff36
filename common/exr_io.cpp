#include "common/exr_io.h"

#include <ImfBoxAttribute.h>
#include <ImfChannelList.h>
#include <ImfDoubleAttribute.h>
#include <ImfFloatAttribute.h>
#include <ImfFloatVectorAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfIO.h>
#include <ImfInputFile.h>
#include <ImfIntAttribute.h>
#include <ImfOutputFile.h>
#include <ImfRgbaFile.h>
#include <ImfStringAttribute.h>
#include <ImfVecAttribute.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <exception>
#include <limits>
#include <system_error>

#include "common/checksum.h"
#include "common/content_hash.h"
#include "common/error.h"

#define STB_IMAGE_IMPLEMENTATION
#define STBI_NO_PSD
#define STBI_NO_PIC
#define STBI_NO_PNM
#define STBI_NO_GIF
#include <stb_image.h>

namespace dofarm {
namespace {

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

// What the root R, G, B hold (dofarm.rgb).
constexpr const char* kRgbReference = "reference";
constexpr const char* kRgbNoisyMean = "noisy_mean";

// String attributes OpenEXR itself defines for multi-part and multi-view
// files; they are never user attributes.
bool is_openexr_string_attribute(const std::string& name) {
  return name == "name" || name == "type" || name == "view";
}

std::string quoted(const std::filesystem::path& path) { return "'" + path.string() + "'"; }

std::string errno_text(int err) { return std::error_code(err, std::generic_category()).message(); }

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

// --- Atomic file writing ----------------------------------------------------

// An Imf::OStream into memory. A frame is encoded whole before any byte
// reaches the disk, so its checksum is computed over the very bytes written
// and nobody has to read the file back for it. OutputFile writes its offset
// table from its destructor, which swallows exceptions, so the first failure
// (out of memory) is remembered: an incomplete encoding must not be written.
class MemOStream : public Imf::OStream {
 public:
  explicit MemOStream(const std::string& name) : Imf::OStream(name.c_str()) {}

  void write(const char c[], int n) override {
    try {
      if (pos_ + size_t(n) > bytes_.size()) bytes_.resize(pos_ + size_t(n));
    } catch (const std::exception& e) {
      error_ = std::string("out of memory encoding the image: ") + e.what();
      throw Iex::IoExc(error_);
    }
    std::memcpy(bytes_.data() + pos_, c, size_t(n));
    pos_ += size_t(n);
  }
  uint64_t tellp() override { return pos_; }
  void seekp(uint64_t pos) override { pos_ = pos; }

  const std::vector<char>& bytes() const { return bytes_; }
  const std::string& error() const { return error_; }

 private:
  std::vector<char> bytes_;
  size_t pos_ = 0;
  std::string error_;
};

// An Imf::IStream over bytes already in memory (memory-mapped in OpenEXR's
// sense: the decoder reads them in place).
class MemIStream : public Imf::IStream {
 public:
  MemIStream(const std::string& name, const std::vector<char>& bytes)
      : Imf::IStream(name.c_str()), bytes_(bytes) {}

  bool isMemoryMapped() const override { return true; }
  char* readMemoryMapped(int n) override {
    if (n < 0 || pos_ + size_t(n) > bytes_.size()) throw Iex::InputExc("unexpected end of file");
    char* p = const_cast<char*>(bytes_.data()) + pos_;
    pos_ += size_t(n);
    return p;
  }
  bool read(char c[], int n) override {
    std::memcpy(c, readMemoryMapped(n), size_t(n));
    return pos_ < bytes_.size();
  }
  uint64_t tellg() override { return pos_; }
  void seekg(uint64_t pos) override { pos_ = pos; }
  void clear() override {}

 private:
  const std::vector<char>& bytes_;
  size_t pos_ = 0;
};

// The whole file in one read. Throws RuntimeError naming it.
std::vector<char> read_whole_file(const std::filesystem::path& path) {
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw RuntimeError("cannot open " + quoted(path) + ": " + errno_text(errno));
  std::vector<char> bytes;
  try {
    struct stat st {};
    if (::fstat(fd, &st) != 0)
      throw RuntimeError("cannot stat " + quoted(path) + ": " + errno_text(errno));
    bytes.resize(size_t(st.st_size));
    size_t done = 0;
    while (done < bytes.size()) {
      ssize_t k = ::pread(fd, bytes.data() + done, bytes.size() - done, off_t(done));
      if (k < 0 && errno == EINTR) continue;
      if (k < 0) throw RuntimeError("cannot read " + quoted(path) + ": " + errno_text(errno));
      if (k == 0) break;  // shrank meanwhile: decode what is there, the reader reports it
      done += size_t(k);
    }
    bytes.resize(done);
  } catch (...) {
    ::close(fd);
    throw;
  }
  ::close(fd);
  return bytes;
}

// Writes all of `bytes` to `fd`. Throws RuntimeError.
void write_all(int fd, const std::vector<char>& bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    ssize_t k = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) throw RuntimeError("write failed: " + errno_text(k < 0 ? errno : EIO));
    done += size_t(k);
  }
}

// Makes a rename durable: the directory entry itself must reach the disk.
void fsync_directory(const std::filesystem::path& dir) {
  int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw RuntimeError("cannot open directory " + quoted(dir) + ": " + errno_text(errno));
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) throw RuntimeError("cannot fsync directory " + quoted(dir) + ": " + errno_text(err));
}

// Writes `header` and `frame_buffer` to `path` so that a reader sees either
// the old file or the complete new one (LevelDB-style temp, fsync, rename).
// This is the one boundary where OpenEXR exceptions become RuntimeError.
uint64_t write_exr_atomically(const std::filesystem::path& path, const Imf::Header& header,
                              const Imf::FrameBuffer& frame_buffer) {
  // The counter keeps two threads of one process writing the same path from
  // sharing a temporary file.
  static std::atomic<unsigned> counter{0};
  const std::filesystem::path tmp = path.string() + ".tmp-" + std::to_string(::getpid()) + "-" +
                                    std::to_string(counter.fetch_add(1));
  const std::filesystem::path dir = path.has_parent_path() ? path.parent_path() : ".";
  int fd = -1;
  try {
    MemOStream stream(tmp.string());
    {
      Imf::OutputFile file(stream, header, 1);
      file.setFrameBuffer(frame_buffer);
      file.writePixels(header.dataWindow().max.y - header.dataWindow().min.y + 1);
    }  // the destructor writes the line offset table
    if (!stream.error().empty()) throw RuntimeError(stream.error());
    const uint64_t sum = checksum64(stream.bytes().data(), stream.bytes().size());
    std::filesystem::create_directories(dir);
    fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) throw RuntimeError("cannot create " + quoted(tmp) + ": " + errno_text(errno));
    write_all(fd, stream.bytes());
    if (::fsync(fd) != 0) throw RuntimeError("fsync failed: " + errno_text(errno));
    int rc = ::close(fd);
    fd = -1;
    if (rc != 0) throw RuntimeError("close failed: " + errno_text(errno));
    std::filesystem::rename(tmp, path);
    fsync_directory(dir);
    return sum;
  } catch (const std::exception& e) {
    if (fd >= 0) ::close(fd);
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    throw RuntimeError("cannot write EXR " + quoted(path) + ": " + e.what());
  }
}

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
  return cam;
}

// --- Image loading ----------------------------------------------------------

std::string lower_extension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext;
}

RgbImage load_exr_rgb(const std::filesystem::path& path) {
  RgbImage img;
  try {
    Imf::InputFile file(path.c_str());
    const Imf::Header& header = file.header();
    const Imath::Box2i dw = header.dataWindow();
    img.width = dw.max.x - dw.min.x + 1;
    img.height = dw.max.y - dw.min.y + 1;
    img.rgb.assign(size_t(img.width) * img.height * 3, 0.0f);
    const Imf::ChannelList& channels = header.channels();
    if (channels.findChannel("R") && channels.findChannel("G") && channels.findChannel("B")) {
      // Read R, G, B as FLOAT whatever their stored type: OpenEXR converts
      // exactly, where RgbaInputFile would round 32-bit data to half.
      Imf::FrameBuffer fb;
      const char* const names[] = {"R", "G", "B"};
      for (int c = 0; c < 3; ++c)
        fb.insert(names[c], Imf::Slice::Make(Imf::FLOAT, img.rgb.data() + c, dw, 3 * sizeof(float),
                                             3 * sizeof(float) * size_t(img.width)));
      file.setFrameBuffer(fb);
      file.readPixels(dw.min.y, dw.max.y);
    } else {
      // Luminance or luminance/chroma files: RgbaInputFile knows how to turn
      // them into RGB (half precision is all such files hold).
      Imf::RgbaInputFile rgba_file(path.c_str());
      if (!(rgba_file.channels() & Imf::WRITE_Y)) throw RuntimeError("no R, G, B or Y channels");
      std::vector<Imf::Rgba> pixels(size_t(img.width) * img.height);
      rgba_file.setFrameBuffer(pixels.data() - dw.min.x - size_t(dw.min.y) * img.width, 1,
                               size_t(img.width));
      rgba_file.readPixels(dw.min.y, dw.max.y);
      for (size_t i = 0; i < pixels.size(); ++i) {
        img.rgb[3 * i + 0] = pixels[i].r;
        img.rgb[3 * i + 1] = pixels[i].g;
        img.rgb[3 * i + 2] = pixels[i].b;
      }
    }
  } catch (const std::exception& e) {
    throw RuntimeError("cannot read image " + quoted(path) + ": " + e.what());
  }
  return img;
}

// Where stb_image reads from: a file, or encoded bytes in memory (a texture
// embedded in a glTF). Both decode through the same code below.
struct StbSource {
  const std::filesystem::path* path = nullptr;
  const stbi_uc* data = nullptr;
  int size = 0;
  bool is_16_bit() const {
    return path ? stbi_is_16_bit(path->c_str()) : stbi_is_16_bit_from_memory(data, size);
  }
  float* loadf(int* w, int* h, int* c) const {
    return path ? stbi_loadf(path->c_str(), w, h, c, 3)
                : stbi_loadf_from_memory(data, size, w, h, c, 3);
  }
  stbi_us* load_16(int* w, int* h, int* c) const {
    return path ? stbi_load_16(path->c_str(), w, h, c, 3)
                : stbi_load_16_from_memory(data, size, w, h, c, 3);
  }
  stbi_uc* load(int* w, int* h, int* c) const {
    return path ? stbi_load(path->c_str(), w, h, c, 3)
                : stbi_load_from_memory(data, size, w, h, c, 3);
  }
};

// Throws RuntimeError naming `what` (the file, or the embedded image).
RgbImage load_stb_rgb(const StbSource& src, const std::string& what, bool hdr, bool srgb) {
  RgbImage img;
  int channels_in_file = 0;
  const size_t n = [&] {
    if (hdr) {
      // Radiance .hdr holds linear radiance; stbi_loadf returns it unchanged.
      float* data = src.loadf(&img.width, &img.height, &channels_in_file);
      if (!data) return size_t(0);
      img.rgb.assign(data, data + size_t(img.width) * img.height * 3);
      stbi_image_free(data);
    } else if (src.is_16_bit()) {
      // 16-bit PNGs keep their precision instead of being cut to 8 bits.
      stbi_us* data = src.load_16(&img.width, &img.height, &channels_in_file);
      if (!data) return size_t(0);
      const size_t count = size_t(img.width) * img.height * 3;
      img.rgb.resize(count);
      for (size_t i = 0; i < count; ++i) {
        float v = data[i] / 65535.0f;
        img.rgb[i] = srgb ? srgb_to_linear(v) : v;
      }
      stbi_image_free(data);
    } else {
      // Not stbi_loadf: for 8-bit files it applies a pure 2.2 gamma, not the
      // sRGB curve. Decode the exact curve through a table of the 256 codes.
      stbi_uc* data = src.load(&img.width, &img.height, &channels_in_file);
      if (!data) return size_t(0);
      float table[256];
      for (int i = 0; i < 256; ++i) table[i] = srgb ? srgb_to_linear(i / 255.0f) : i / 255.0f;
      const size_t count = size_t(img.width) * img.height * 3;
      img.rgb.resize(count);
      for (size_t i = 0; i < count; ++i) img.rgb[i] = table[data[i]];
      stbi_image_free(data);
    }
    return img.rgb.size();
  }();
  if (n == 0) {
    const char* reason = stbi_failure_reason();
    throw RuntimeError("cannot read image " + what + ": " +
                       (reason ? reason : "unknown stb_image error"));
  }
  return img;
}

// Textures and environment maps feed the renderer, which must never see a
// NaN, an Inf or negative radiance; such texels are zeroed here, once, and
// counted so the caller can warn.
void sanitize(RgbImage* img) {
  for (float& v : img->rgb) {
    if (!(v >= 0.0f) || std::isinf(v)) {
      v = 0.0f;
      ++img->sanitized_values;
    }
  }
}

}  // namespace

// --- Public API -------------------------------------------------------------

RgbImage load_rgb_image(const std::filesystem::path& path, bool srgb) {
  const std::string ext = lower_extension(path);
  note_input_file(path);  // a job's snapshot holds every image it reads
  RgbImage img;
  if (ext == ".exr") {
    img = load_exr_rgb(path);
  } else if (ext == ".hdr") {
    img = load_stb_rgb(StbSource{&path}, quoted(path), /*hdr=*/true, srgb);
  } else if (ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".tga" || ext == ".bmp") {
    img = load_stb_rgb(StbSource{&path}, quoted(path), /*hdr=*/false, srgb);
  } else {
    throw RuntimeError("cannot read image " + quoted(path) + ": unknown extension '" + ext +
                       "' (expected .exr, .hdr, .png, .jpg, .jpeg, .tga or .bmp)");
  }
  sanitize(&img);
  return img;
}

RgbImage decode_rgb_image(const void* data, size_t size, const std::string& name, bool srgb) {
  const std::string what = std::string(1, '"').append(name).append(1, '"');
  if (size == 0 || size > size_t(std::numeric_limits<int>::max()))
    throw RuntimeError("cannot read image " + what + ": " + std::to_string(size) + " bytes");
  StbSource src{nullptr, static_cast<const stbi_uc*>(data), int(size)};
  const bool hdr = stbi_is_hdr_from_memory(src.data, src.size) != 0;
  RgbImage img = load_stb_rgb(src, what, hdr, srgb);
  sanitize(&img);
  return img;
}

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

// IEC 61966-2-1: linear segment below the knee, 2.4 power above it.
float srgb_to_linear(float v) {
  if (v <= 0.04045f) return v / 12.92f;
  return std::pow((v + 0.055f) / 1.055f, 2.4f);
}

float linear_to_srgb(float v) {
  if (v <= 0.0031308f) return v * 12.92f;
  return 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

}  // namespace dofarm
