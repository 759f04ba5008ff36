// What assimp 5.2 loses of a Collada or FBX file's cameras: whether a camera
// is orthographic, and its size. Its Collada importer takes <orthographic>'s
// xmag for a field of view in degrees (Blender's Orthographic Scale 6 comes
// out as a 3-degree perspective camera), and its FBX importer ignores
// CameraProjectionType, so both would render a Blender user's orthographic
// camera as a perspective one, silently. These scans read just that from
// the file, so that the loader can render the camera as the file defines it
// (Collada: COLLADA 1.4.1 spec, <orthographic>; FBX from Blender: its
// OrthoZoom) or refuse it by name (FBX from elsewhere).
#pragma once

#include <filesystem>
#include <set>
#include <string>
#include <vector>

namespace dofarm::render {

struct ForeignCamera {
  // Collada's camera element; binary FBX: empty id, the name of the camera's
  // Model (the node assimp names the camera after), in binary and ASCII
  // files alike.
  std::string id, name;
  bool orthographic = false;
  // Collada <orthographic>: half the film's width and height in scene units
  // (0 where the file gives neither it nor the aspect ratio to derive it).
  double xmag = 0, ymag = 0;
  std::string node;  // Collada: the name of the node that instantiates it
  double ortho_zoom = 0;  // FBX: the camera's OrthoZoom (template default: 1)
};

struct ForeignCameras {
  enum class Format { kOther, kCollada, kFbx };
  Format format = Format::kOther;
  // FBX: every camera, by its Model's name; where the records cannot be
  // read, one unnamed entry per orthographic camera only.
  std::vector<ForeignCamera> cameras;
  // FBX: the file's last OrthoZoom, which is its only camera's (the
  // template's default, 1, when the camera keeps it); 0 without any.
  // Blender writes its Orthographic Scale there, in Blender units.
  double fbx_ortho_zoom = 0;

  bool any_orthographic() const;
  // The camera that assimp names `ai_name` (Collada: the instantiating node's
  // name, else the camera's own name or id, else the file's only camera);
  // null where it cannot be told.
  const ForeignCamera* find(const std::string& ai_name) const;
};

// The cameras of a file's bytes: Collada text (.dae), binary or ASCII FBX
// (.fbx).
ForeignCameras scan_collada_cameras(const std::string& text);
ForeignCameras scan_fbx_cameras(const std::string& bytes);
// A binary FBX file's node records, as far as the camera scan needs them
// (FBX 7.x binary layout as the Blender developers documented it in 2013,
// "FBX binary file format specification": a 27-byte header with the
// version; per record an end offset, a property count and byte length, a
// name, typed properties, nested records and a null record; 64-bit offsets
// from version 7500). Array properties are skipped, not kept.
// Empty when the bytes are not a well-formed binary FBX file.
struct FbxNode {
  struct Property {
    char type = 0;  // 'S' string (and 'R' raw), 'L' 'I' 'Y' 'C' integers, 'D' 'F' reals
    int64_t i = 0;  // integer types
    double d = 0;   // every numeric type
    std::string s;  // 'S' and 'R'
  };
  std::string name;
  std::vector<Property> properties;
  std::vector<FbxNode> children;
};
std::vector<FbxNode> parse_fbx_binary(const std::string& bytes);
// The same records from an FBX ASCII file (FbxAsciiParser in the .cpp has
// the grammar): integers as 'L', reals as 'D', strings and flag letters
// as 'S', a Model's name as written ("Model::Name"), arrays skipped.
// Empty when the text is not a well-formed ASCII FBX file.
std::vector<FbxNode> parse_fbx_ascii(const std::string& text);

// The numeric values of every FBX property `name` (P: "name", type, label,
// flags, value) in a binary or ASCII file, in file order.
std::vector<double> fbx_property_values(const std::string& bytes, const std::string& name);

// Collada: the ids of the geometries that an <instance_geometry> places
// without a <bind_material> (and that no other instance binds). assimp 5.2
// gives them the file's first material; Blender, whose exporter writes an
// object without a material so, renders them in its grey default surface.
std::set<std::string> collada_unbound_geometries(const std::string& text);

// The file name's extension in lower case (".dae", ".glb").
std::string lower_extension(const std::filesystem::path& path);

}  // namespace dofarm::render
