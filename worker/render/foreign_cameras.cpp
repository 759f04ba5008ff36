#include "worker/render/foreign_cameras.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <iterator>
#include <map>
#include <regex>
#include <type_traits>

#include "common/error.h"

namespace dofarm::render {

namespace {

// The value of attribute `name` in the start tag text `tag` ("" if absent).
std::string attribute(const std::string& tag, const std::string& name) {
  const std::regex re("\\s" + name + "\\s*=\\s*\"([^\"]*)\"");
  std::smatch m;
  return std::regex_search(tag, m, re) ? m[1].str() : std::string();
}

// The number inside the first <element ...>number</element> of `text`; 0
// where there is none or it is not a finite positive number.
double element_number(const std::string& text, const std::string& element) {
  const std::regex re("<" + element + "(\\s[^>]*)?>\\s*([^<\\s]+)\\s*</" + element + ">");
  std::smatch m;
  if (!std::regex_search(text, m, re)) return 0;
  const std::string s = m[2].str();
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  return end == s.c_str() + s.size() && std::isfinite(v) && v > 0 ? v : 0;
}

// Start positions of the tags "<name" followed by white space, '>' or '/'.
std::vector<size_t> tags(const std::string& text, const std::string& name) {
  std::vector<size_t> at;
  const std::string open = "<" + name;
  for (size_t p = text.find(open); p != std::string::npos; p = text.find(open, p + 1)) {
    const size_t after = p + open.size();
    if (after < text.size() && (std::isspace(static_cast<unsigned char>(text[after])) ||
                                text[after] == '>' || text[after] == '/'))
      at.push_back(p);
  }
  return at;
}

std::string start_tag(const std::string& text, size_t at) {
  const size_t end = text.find('>', at);
  return text.substr(at, end == std::string::npos ? std::string::npos : end - at + 1);
}

// Whether a start tag closes itself (<name ... />).
bool self_closing(const std::string& tag) { return tag.size() >= 2 && tag[tag.size() - 2] == '/'; }

}  // namespace

bool ForeignCameras::any_orthographic() const {
  return std::any_of(cameras.begin(), cameras.end(),
                     [](const ForeignCamera& c) { return c.orthographic; });
}

const ForeignCamera* ForeignCameras::find(const std::string& ai_name) const {
  for (const ForeignCamera& c : cameras)
    if (!c.node.empty() && c.node == ai_name) return &c;
  for (const ForeignCamera& c : cameras)
    if ((!c.name.empty() && c.name == ai_name) || (!c.id.empty() && c.id == ai_name)) return &c;
  return format == Format::kCollada && cameras.size() == 1 ? &cameras.front() : nullptr;
}

// COLLADA 1.4.1: <library_cameras><camera id name><optics><technique_common>
// holds <perspective> or <orthographic> with xmag and/or ymag and
// aspect_ratio = xmag / ymag (any two of the three). A node's
// <instance_camera url="#id"> comes before its child nodes (the schema's
// order), so the last <node> tag opened before it is the node that holds it.
ForeignCameras scan_collada_cameras(const std::string& text) {
  ForeignCameras out;
  out.format = ForeignCameras::Format::kCollada;
  for (size_t at : tags(text, "camera")) {
    const std::string tag = start_tag(text, at);
    size_t end = text.find("</camera>", at);
    if (self_closing(tag)) end = at + tag.size();
    const std::string body =
        text.substr(at, end == std::string::npos ? std::string::npos : end - at);
    ForeignCamera c;
    c.id = attribute(tag, "id");
    c.name = attribute(tag, "name");
    const size_t ortho = body.find("<orthographic");
    if (ortho != std::string::npos) {
      c.orthographic = true;
      const size_t ortho_end = body.find("</orthographic>", ortho);
      const std::string optics = body.substr(
          ortho, ortho_end == std::string::npos ? std::string::npos : ortho_end - ortho);
      double x = element_number(optics, "xmag"), y = element_number(optics, "ymag");
      const double aspect = element_number(optics, "aspect_ratio");
      if (x > 0 && !(y > 0) && aspect > 0) y = x / aspect;
      if (y > 0 && !(x > 0) && aspect > 0) x = y * aspect;
      c.xmag = x;
      c.ymag = y;
    }
    out.cameras.push_back(c);
  }
  const std::vector<size_t> nodes = tags(text, "node");
  for (size_t at : tags(text, "instance_camera")) {
    std::string url = attribute(start_tag(text, at), "url");
    if (!url.empty() && url[0] == '#') url.erase(0, 1);
    auto holder = std::upper_bound(nodes.begin(), nodes.end(), at);
    if (holder == nodes.begin()) continue;
    const std::string node_tag = start_tag(text, *std::prev(holder));
    std::string node = attribute(node_tag, "name");
    if (node.empty()) node = attribute(node_tag, "id");
    for (ForeignCamera& c : out.cameras)
      if (c.id == url && c.node.empty()) c.node = node;
  }
  return out;
}

// The numeric values of every FBX property `name` in the file, in file
// order. A property is P: "Name", "type", "label", "flags", value... In a
// binary file that is a typed list: 'S' + uint32 length + bytes for each
// string, then the value: 'I' int32, 'L' int64, 'D' double, 'F' float
// (little-endian, as FBX is). In an ASCII file, text after the four quoted
// strings.
std::vector<double> fbx_property_values(const std::string& bytes, const std::string& name) {
  static const std::string kBinaryMagic("Kaydara FBX Binary  \0", 21);
  std::vector<double> values;
  if (bytes.compare(0, kBinaryMagic.size(), kBinaryMagic) == 0) {
    for (size_t p = bytes.find(name); p != std::string::npos; p = bytes.find(name, p + 1)) {
      // The name is itself an 'S' string of exactly these bytes.
      uint32_t own = 0;
      if (p < 5 || bytes[p - 5] != 'S') continue;
      std::memcpy(&own, bytes.data() + p - 4, 4);
      if (own != name.size()) continue;
      size_t q = p + name.size();
      bool ok = true;
      for (int s = 0; s < 3 && ok; ++s) {  // the type, the label and the flags
        uint32_t len = 0;
        ok = q + 5 <= bytes.size() && bytes[q] == 'S';
        if (!ok) break;
        std::memcpy(&len, bytes.data() + q + 1, 4);
        q += 5 + size_t(len);
      }
      if (!ok || q + 5 > bytes.size()) continue;
      const char type = bytes[q];
      const size_t width = type == 'I' || type == 'F' ? 4 : type == 'L' || type == 'D' ? 8 : 0;
      if (width == 0 || q + 1 + width > bytes.size()) continue;
      const char* at = bytes.data() + q + 1;
      if (type == 'I') {
        int32_t v;
        std::memcpy(&v, at, 4);
        values.push_back(v);
      } else if (type == 'L') {
        int64_t v;
        std::memcpy(&v, at, 8);
        values.push_back(double(v));
      } else if (type == 'F') {
        float v;
        std::memcpy(&v, at, 4);
        values.push_back(v);
      } else {
        double v;
        std::memcpy(&v, at, 8);
        values.push_back(v);
      }
    }
    return values;
  }
  const std::string quoted = "\"" + name + "\"";
  for (size_t p = bytes.find(quoted); p != std::string::npos; p = bytes.find(quoted, p + 1)) {
    size_t q = p + quoted.size();
    bool ok = true;
    for (int s = 0; s < 3 && ok; ++s) {  // , "type" , "label" , "flags"
      q = bytes.find_first_not_of(" \t", q);
      ok = q != std::string::npos && bytes[q] == ',';
      if (ok) q = bytes.find_first_not_of(" \t", q + 1);
      ok = ok && q != std::string::npos && bytes[q] == '"';
      if (ok) q = bytes.find('"', q + 1);
      ok = ok && q != std::string::npos;
      if (ok) ++q;
    }
    if (!ok) continue;
    q = bytes.find_first_not_of(" \t", q);
    if (q == std::string::npos || bytes[q] != ',') continue;
    const char* start = bytes.c_str() + q + 1;
    char* end = nullptr;
    const double v = std::strtod(start, &end);
    if (end != start) values.push_back(v);
  }
  return values;
}

namespace {

// Little-endian reads within `bytes`; false past its end.
template <typename T>
bool read_le(const std::string& bytes, size_t at, T* v) {
  if (at > bytes.size() || bytes.size() - at < sizeof(T)) return false;
  std::memcpy(v, bytes.data() + at, sizeof(T));
  return true;
}

class FbxBinaryParser {
 public:
  explicit FbxBinaryParser(const std::string& bytes) : b_(bytes) {}

  bool parse(std::vector<FbxNode>* top) {
    static const std::string kMagic("Kaydara FBX Binary  \0", 21);
    uint32_t version = 0;
    if (b_.compare(0, kMagic.size(), kMagic) != 0 || !read_le(b_, 23, &version)) return false;
    wide_ = version >= 7500;
    size_t at = 27;
    return records(&at, b_.size(), 0, top);
  }

 private:
  // The records from `*at` up to a null record (or `end`), into `out`.
  bool records(size_t* at, size_t end, int depth, std::vector<FbxNode>* out) {
    if (depth > 64) return false;  // no file nests this deep; a loop would
    while (*at < end) {
      uint64_t end_offset = 0, count = 0, list_len = 0;
      uint8_t name_len = 0;
      const size_t head = wide_ ? 25 : 13;
      if (!offset(*at, &end_offset) || !offset(*at + (wide_ ? 8 : 4), &count) ||
          !offset(*at + (wide_ ? 16 : 8), &list_len) ||
          !read_le(b_, *at + (wide_ ? 24 : 12), &name_len))
        return false;
      if (end_offset == 0) {  // the null record closing a nested list (or the top's end)
        *at += head;
        return true;
      }
      const size_t name_at = *at + head;
      const size_t props_at = name_at + name_len;
      if (end_offset <= *at || end_offset > end || props_at > end_offset ||
          list_len > end_offset - props_at)
        return false;
      FbxNode node;
      node.name = b_.substr(name_at, name_len);
      size_t p = props_at;
      for (uint64_t k = 0; k < count; ++k)
        if (!property(&p, props_at + list_len, &node.properties)) return false;
      if (p != props_at + list_len) return false;
      if (p < end_offset && !records(&p, end_offset, depth + 1, &node.children)) return false;
      out->push_back(std::move(node));
      *at = end_offset;
    }
    return true;
  }

  bool offset(size_t at, uint64_t* v) {
    if (wide_) return read_le(b_, at, v);
    uint32_t u = 0;
    if (!read_le(b_, at, &u)) return false;
    *v = u;
    return true;
  }

  bool property(size_t* p, size_t end, std::vector<FbxNode::Property>* out) {
    if (*p >= end) return false;
    FbxNode::Property prop;
    prop.type = b_[*p];
    const size_t at = *p + 1;
    size_t width = 0;
    bool ok = true;
    switch (prop.type) {
      case 'Y':
        ok = take<int16_t>(at, &prop, &width);
        break;
      case 'C':
        ok = take<uint8_t>(at, &prop, &width);
        break;
      case 'I':
        ok = take<int32_t>(at, &prop, &width);
        break;
      case 'L':
        ok = take<int64_t>(at, &prop, &width);
        break;
      case 'F':
        ok = take<float>(at, &prop, &width);
        break;
      case 'D':
        ok = take<double>(at, &prop, &width);
        break;
      case 'S':
      case 'R': {
        uint32_t len;
        if (!read_le(b_, at, &len) || len > end - std::min(end, at + 4)) return false;
        prop.s = b_.substr(at + 4, len);
        width = 4 + size_t(len);
        break;
      }
      case 'f':
      case 'd':
      case 'l':
      case 'i':
      case 'b': {  // array: count, encoding, byte length, then the (maybe deflated) bytes
        uint32_t stored;
        if (!read_le(b_, at + 8, &stored)) return false;
        width = 12 + size_t(stored);
        break;
      }
      default:
        return false;
    }
    if (!ok) return false;
    if (prop.type != 'D' && prop.type != 'F') prop.d = double(prop.i);
    if (width > end - std::min(end, at)) return false;
    *p = at + width;
    if (prop.type != 'f' && prop.type != 'd' && prop.type != 'l' && prop.type != 'i' &&
        prop.type != 'b')
      out->push_back(std::move(prop));
    return true;
  }

  // A number of type T at `at` into prop (i for integers, d for reals).
  template <typename T>
  bool take(size_t at, FbxNode::Property* prop, size_t* width) {
    T v;
    if (!read_le(b_, at, &v)) return false;
    if constexpr (std::is_floating_point_v<T>)
      prop->d = double(v);
    else
      prop->i = int64_t(v);
    *width = sizeof(T);
    return true;
  }

  const std::string& b_;
  bool wide_ = false;
};

// FBX ASCII, as the FBX SDK writes it: per node "Name:" then values
// separated by commas (a comma at a line's end continues the list on the
// next line), then "{" with nested nodes up to "}", or the line's end.
// Values are quoted strings (no escapes; a quote is written &quot;),
// numbers, and bare letters (T, F, Y, N: flags); an array is "*count"
// with its numbers in a nested "a:" node, skipped here as the binary
// parser skips arrays. ';' starts a comment to the line's end. Integers
// come out as 'L' (i and d), reals as 'D', strings and letters as 'S'.
class FbxAsciiParser {
 public:
  explicit FbxAsciiParser(const std::string& text) : t_(text) {}

  bool parse(std::vector<FbxNode>* top) {
    if (!nodes(0, top) || at_ != t_.size()) return false;
    return !top->empty();
  }

 private:
  // Nodes up to a closing '}' (depth > 0, left unconsumed) or the end.
  bool nodes(int depth, std::vector<FbxNode>* out) {
    if (depth > 64) return false;  // no file nests this deep
    for (;;) {
      skip_space(true);
      if (at_ == t_.size()) return depth == 0;
      if (t_[at_] == '}') return depth > 0;
      FbxNode node;
      const size_t name_at = at_;
      while (at_ < t_.size() && (std::isalnum(static_cast<unsigned char>(t_[at_])) ||
                                 t_[at_] == '_' || t_[at_] == '|'))
        ++at_;
      if (at_ == name_at || at_ == t_.size() || t_[at_] != ':') return false;
      node.name = t_.substr(name_at, at_ - name_at);
      ++at_;
      bool array = false;
      skip_space(false);
      while (at_ < t_.size() && t_[at_] != '\n' && t_[at_] != '\r' && t_[at_] != '{' &&
             t_[at_] != '}' && t_[at_] != ';') {
        if (t_[at_] == ',') {  // an empty first value ("Content: ,\"...\"")
          ++at_;
          skip_space(true);
          continue;
        }
        if (!value(&node.properties, &array)) return false;
        skip_space(false);
        if (at_ < t_.size() && t_[at_] == ',') {
          ++at_;
          skip_space(true);  // the list goes on, on this line or the next
        }
      }
      if (at_ < t_.size() && t_[at_] == '{') {
        ++at_;
        if (array) {  // "*count { a: numbers }": skipped
          const size_t close = t_.find('}', at_);
          if (close == std::string::npos) return false;
          at_ = close + 1;
        } else {
          if (!nodes(depth + 1, &node.children)) return false;
          ++at_;  // the '}'
        }
      }
      out->push_back(std::move(node));
    }
  }

  bool value(std::vector<FbxNode::Property>* out, bool* array) {
    FbxNode::Property prop;
    const char c = t_[at_];
    if (c == '"') {
      const size_t close = t_.find('"', at_ + 1);
      if (close == std::string::npos) return false;
      prop.type = 'S';
      for (size_t q = at_ + 1; q < close;) {
        if (t_.compare(q, 6, "&quot;") == 0) {
          prop.s += '"';
          q += 6;
        } else {
          prop.s += t_[q++];
        }
      }
      at_ = close + 1;
    } else if (c == '*') {  // an array's count
      ++at_;
      while (at_ < t_.size() && std::isdigit(static_cast<unsigned char>(t_[at_]))) ++at_;
      *array = true;
      return true;
    } else if (std::isalpha(static_cast<unsigned char>(c))) {
      const size_t from = at_;
      while (at_ < t_.size() && std::isalnum(static_cast<unsigned char>(t_[at_]))) ++at_;
      prop.type = 'S';
      prop.s = t_.substr(from, at_ - from);
    } else {
      const char* start = t_.c_str() + at_;
      char* end = nullptr;
      errno = 0;
      const long long i = std::strtoll(start, &end, 10);
      char* end_d = nullptr;
      const double d = std::strtod(start, &end_d);
      if (end_d == start) return false;
      if (end == end_d && errno == 0) {
        prop.type = 'L';
        prop.i = i;
        prop.d = double(i);
      } else {
        prop.type = 'D';
        prop.d = d;
      }
      at_ += size_t(end_d - start);
    }
    out->push_back(std::move(prop));
    return true;
  }

  // Blanks and comments; line ends too where `lines`.
  void skip_space(bool lines) {
    while (at_ < t_.size()) {
      const char c = t_[at_];
      if (c == ' ' || c == '\t' || (lines && (c == '\n' || c == '\r'))) {
        ++at_;
      } else if (c == ';') {
        const size_t eol = t_.find('\n', at_);
        at_ = eol == std::string::npos ? t_.size() : eol;
      } else {
        return;
      }
    }
  }

  const std::string& t_;
  size_t at_ = 0;
};

const FbxNode* child(const FbxNode& n, const std::string& name) {
  for (const FbxNode& c : n.children)
    if (c.name == name) return &c;
  return nullptr;
}

// The numbers of a Properties70 list that a camera scan wants: P records
// ("name", "type", "label", "flags", value).
void camera_properties(const FbxNode* props70, bool* ortho, double* zoom) {
  if (!props70) return;
  for (const FbxNode& p : props70->children) {
    if (p.name != "P" || p.properties.size() < 5 || p.properties[0].type != 'S') continue;
    const FbxNode::Property& v = p.properties[4];
    if (v.type == 'S' || v.type == 'R') continue;
    if (p.properties[0].s == "CameraProjectionType") *ortho = v.i == 1;
    if (p.properties[0].s == "OrthoZoom") *zoom = v.d;
  }
}

// Every camera of a parsed FBX file, named by the Model that its
// NodeAttribute is connected to ("C", "OO", attribute id, model id). A
// Model's name is "Name\0\1Model" in binary files and "Model::Name" in
// ASCII ones; assimp names the camera after the node, "Name". Empty when
// the file has no such structure.
std::vector<ForeignCamera> fbx_file_cameras(const std::vector<FbxNode>& top) {
  bool default_ortho = false;
  double default_zoom = 1;  // FBX SDK default, which the template restates
  std::map<int64_t, std::pair<bool, double>> attributes;  // id -> (ortho, zoom)
  std::map<int64_t, std::string> models;                  // id -> name
  std::vector<ForeignCamera> out;
  for (const FbxNode& n : top) {
    if (n.name == "Definitions") {
      for (const FbxNode& type : n.children) {
        if (type.name != "ObjectType" || type.properties.empty() ||
            type.properties[0].s != "NodeAttribute")
          continue;
        for (const FbxNode& t : type.children)
          if (t.name == "PropertyTemplate" && !t.properties.empty() &&
              t.properties[0].s == "FbxCamera")
            camera_properties(child(t, "Properties70"), &default_ortho, &default_zoom);
      }
    }
  }
  for (const FbxNode& n : top) {
    if (n.name != "Objects") continue;
    for (const FbxNode& o : n.children) {
      if (o.properties.size() < 3 || o.properties[0].type != 'L' || o.properties[2].s != "Camera")
        continue;
      if (o.name == "NodeAttribute") {
        bool ortho = default_ortho;
        double zoom = default_zoom;
        camera_properties(child(o, "Properties70"), &ortho, &zoom);
        attributes[o.properties[0].i] = {ortho, zoom};
      } else if (o.name == "Model") {
        const std::string& full = o.properties[1].s;
        const size_t sep = full.find(std::string("\0\1", 2));
        const size_t ascii = full.find("::");
        models[o.properties[0].i] = sep != std::string::npos     ? full.substr(0, sep)
                                    : ascii != std::string::npos ? full.substr(ascii + 2)
                                                                 : full;
      }
    }
  }
  for (const FbxNode& n : top) {
    if (n.name != "Connections") continue;
    for (const FbxNode& c : n.children) {
      if (c.name != "C" || c.properties.size() < 3 || c.properties[0].s != "OO") continue;
      const auto a = attributes.find(c.properties[1].i);
      const auto m = models.find(c.properties[2].i);
      if (a == attributes.end() || m == models.end()) continue;
      ForeignCamera cam;
      cam.name = m->second;
      cam.orthographic = a->second.first;
      cam.ortho_zoom = a->second.second;
      out.push_back(cam);
    }
  }
  return out;
}

}  // namespace

std::vector<FbxNode> parse_fbx_binary(const std::string& bytes) {
  std::vector<FbxNode> top;
  FbxBinaryParser parser(bytes);
  if (!parser.parse(&top)) top.clear();
  return top;
}

std::vector<FbxNode> parse_fbx_ascii(const std::string& text) {
  std::vector<FbxNode> top;
  FbxAsciiParser parser(text);
  if (!parser.parse(&top)) top.clear();
  return top;
}

// FBX keeps a camera's projection in its NodeAttribute's Properties70:
// CameraProjectionType 0 (perspective) or 1 (orthographic), and an
// orthographic camera's OrthoZoom. The Definitions' template, which comes
// first in the file, carries the defaults (0 and 1); a camera whose value
// differs carries its own.
ForeignCameras scan_fbx_cameras(const std::string& bytes) {
  ForeignCameras out;
  out.format = ForeignCameras::Format::kFbx;
  // Each camera by its Model's name, from the binary or ASCII records;
  // failing those (a file cut short, or one that is neither), the file's
  // properties alone.
  std::vector<FbxNode> top = parse_fbx_binary(bytes);
  if (top.empty()) top = parse_fbx_ascii(bytes);
  if (!top.empty()) {
    out.cameras = fbx_file_cameras(top);
    if (!out.cameras.empty()) return out;
  }
  for (double v : fbx_property_values(bytes, "CameraProjectionType")) {
    if (v == 1) {
      ForeignCamera c;
      c.orthographic = true;
      out.cameras.push_back(c);
    }
  }
  const std::vector<double> zoom = fbx_property_values(bytes, "OrthoZoom");
  if (!zoom.empty()) out.fbx_ortho_zoom = zoom.back();
  return out;
}

std::set<std::string> collada_unbound_geometries(const std::string& text) {
  std::set<std::string> bound, unbound;
  for (size_t at : tags(text, "instance_geometry")) {
    const std::string tag = start_tag(text, at);
    std::string url = attribute(tag, "url");
    if (!url.empty() && url[0] == '#') url.erase(0, 1);
    if (url.empty()) continue;
    bool binds = false;
    if (!self_closing(tag)) {
      const size_t end = text.find("</instance_geometry>", at);
      const size_t bind = text.find("<bind_material", at);
      binds = bind != std::string::npos && (end == std::string::npos || bind < end);
    }
    (binds ? bound : unbound).insert(url);
  }
  for (const std::string& id : bound) unbound.erase(id);
  return unbound;
}

std::string lower_extension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

}  // namespace dofarm::render
