// glTF 2.0 import. tinygltf parses; this file checks everything tinygltf takes on trust
// (field types, index ranges, accessor bounds, node cycles) before reading a byte through it,
// so a malformed file is one clear error and never a crash or a hang.
#include <nlohmann/json.hpp>
#include <tiny_gltf.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>

#include "scene/gltf.h"
#include "volume/input_error.h"
#include "volume/input_file.h"

namespace iso {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

std::string oneLine(std::string s) {
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
  for (char& c : s)
    if (c == '\n') c = ';';
  return s;
}

// Field types tinygltf would silently ignore when wrong ("mesh": "0" leaves a node without
// its mesh). Paths use * for every array element or object member.
enum class Kind { Int, Number, Bool, String, Object, Array, IntArray, NumberArray };

struct Rule {
  const char* path;
  Kind kind;
};

const Rule kRules[] = {
    {"/scene", Kind::Int},
    {"/scenes", Kind::Array}, {"/scenes/*/nodes", Kind::IntArray},
    {"/nodes", Kind::Array}, {"/nodes/*", Kind::Object}, {"/nodes/*/mesh", Kind::Int},
    {"/nodes/*/camera", Kind::Int}, {"/nodes/*/skin", Kind::Int},
    {"/nodes/*/children", Kind::IntArray}, {"/nodes/*/matrix", Kind::NumberArray},
    {"/nodes/*/translation", Kind::NumberArray}, {"/nodes/*/rotation", Kind::NumberArray},
    {"/nodes/*/scale", Kind::NumberArray}, {"/nodes/*/name", Kind::String},
    {"/nodes/*/extensions/KHR_lights_punctual/light", Kind::Int},
    {"/meshes", Kind::Array}, {"/meshes/*", Kind::Object}, {"/meshes/*/primitives", Kind::Array},
    {"/meshes/*/primitives/*", Kind::Object}, {"/meshes/*/primitives/*/attributes", Kind::Object},
    {"/meshes/*/primitives/*/attributes/*", Kind::Int}, {"/meshes/*/primitives/*/indices", Kind::Int},
    {"/meshes/*/primitives/*/material", Kind::Int}, {"/meshes/*/primitives/*/mode", Kind::Int},
    {"/accessors", Kind::Array}, {"/accessors/*", Kind::Object}, {"/accessors/*/bufferView", Kind::Int},
    {"/accessors/*/byteOffset", Kind::Int}, {"/accessors/*/componentType", Kind::Int},
    {"/accessors/*/count", Kind::Int}, {"/accessors/*/type", Kind::String},
    {"/accessors/*/normalized", Kind::Bool},
    {"/bufferViews", Kind::Array}, {"/bufferViews/*", Kind::Object}, {"/bufferViews/*/buffer", Kind::Int},
    {"/bufferViews/*/byteOffset", Kind::Int}, {"/bufferViews/*/byteLength", Kind::Int},
    {"/bufferViews/*/byteStride", Kind::Int},
    {"/buffers", Kind::Array}, {"/buffers/*", Kind::Object}, {"/buffers/*/byteLength", Kind::Int},
    {"/buffers/*/uri", Kind::String},
    {"/materials", Kind::Array}, {"/materials/*", Kind::Object},
    {"/materials/*/pbrMetallicRoughness", Kind::Object},
    {"/materials/*/pbrMetallicRoughness/baseColorFactor", Kind::NumberArray},
    {"/materials/*/pbrMetallicRoughness/metallicFactor", Kind::Number},
    {"/materials/*/pbrMetallicRoughness/roughnessFactor", Kind::Number},
    {"/materials/*/pbrMetallicRoughness/baseColorTexture/index", Kind::Int},
    {"/materials/*/pbrMetallicRoughness/metallicRoughnessTexture/index", Kind::Int},
    {"/materials/*/normalTexture/index", Kind::Int}, {"/materials/*/normalTexture/scale", Kind::Number},
    {"/materials/*/emissiveTexture/index", Kind::Int}, {"/materials/*/emissiveFactor", Kind::NumberArray},
    {"/materials/*/doubleSided", Kind::Bool},
    {"/materials/*/extensions/KHR_materials_emissive_strength/emissiveStrength", Kind::Number},
    {"/textures", Kind::Array}, {"/textures/*", Kind::Object}, {"/textures/*/source", Kind::Int},
    {"/textures/*/sampler", Kind::Int},
    {"/images", Kind::Array}, {"/images/*", Kind::Object}, {"/images/*/uri", Kind::String},
    {"/images/*/bufferView", Kind::Int},
    {"/cameras", Kind::Array}, {"/cameras/*", Kind::Object}, {"/cameras/*/type", Kind::String},
    {"/cameras/*/perspective/yfov", Kind::Number},
    {"/extensionsRequired", Kind::Array}, {"/extensionsUsed", Kind::Array},
    {"/extensions/KHR_lights_punctual/lights", Kind::Array},
    {"/extensions/KHR_lights_punctual/lights/*/type", Kind::String},
    {"/extensions/KHR_lights_punctual/lights/*/intensity", Kind::Number},
    {"/extensions/KHR_lights_punctual/lights/*/color", Kind::NumberArray},
};

bool hasKind(const Json& j, Kind kind) {
  auto all = [&](auto pred) {
    if (!j.is_array()) return false;
    for (const Json& e : j)
      if (!pred(e)) return false;
    return true;
  };
  switch (kind) {
    // Every integer of glTF is an index, a count, an offset or an enum: none is negative (and
    // tinygltf reads -1 as "absent", so a -5 would otherwise pass silently).
    case Kind::Int: return j.is_number_unsigned() || (j.is_number_integer() && j.get<long long>() >= 0);
    case Kind::Number: return j.is_number();
    case Kind::Bool: return j.is_boolean();
    case Kind::String: return j.is_string();
    case Kind::Object: return j.is_object();
    case Kind::Array: return j.is_array();
    case Kind::IntArray:
      return all([](const Json& e) { return e.is_number_unsigned() || (e.is_number_integer() && e.get<long long>() >= 0); });
    case Kind::NumberArray: return all([](const Json& e) { return e.is_number(); });
  }
  return false;
}

const char* kindName(Kind kind) {
  switch (kind) {
    case Kind::Int: return "a whole number >= 0";
    case Kind::Number: return "a number";
    case Kind::Bool: return "true or false";
    case Kind::String: return "a string";
    case Kind::Object: return "an object";
    case Kind::Array: return "an array";
    case Kind::IntArray: return "an array of whole numbers >= 0";
    case Kind::NumberArray: return "an array of numbers";
  }
  return "?";
}

void checkRule(const Json& j, const std::string& pattern, size_t pos, const std::string& at,
               Kind kind, const std::string& file) {
  if (pos >= pattern.size()) {
    if (!hasKind(j, kind)) throw InputError(file, at, std::string("expected ") + kindName(kind));
    return;
  }
  const size_t next = pattern.find('/', pos + 1);
  const std::string key = pattern.substr(pos + 1, next == std::string::npos ? std::string::npos : next - pos - 1);
  const size_t rest = next == std::string::npos ? pattern.size() : next;
  if (key == "*") {
    if (j.is_array())
      for (size_t i = 0; i < j.size(); ++i) checkRule(j[i], pattern, rest, at + "/" + std::to_string(i), kind, file);
    else if (j.is_object())
      for (auto it = j.begin(); it != j.end(); ++it) checkRule(*it, pattern, rest, at + "/" + it.key(), kind, file);
    return;
  }
  if (!j.is_object()) return;
  auto it = j.find(key);
  if (it != j.end()) checkRule(*it, pattern, rest, at + "/" + key, kind, file);
}

// The JSON chunk of a .glb, after checking the container against the file's real size.
std::string glbJson(const std::string& bytes, const std::string& file) {
  auto u32 = [&](size_t at) {
    uint32_t v;
    std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  if (bytes.size() < 20 || bytes.compare(0, 4, "glTF") != 0)
    throw InputError(file, "header", "not a binary glTF file (no 'glTF' magic)");
  if (u32(4) != 2) throw InputError(file, "header", "glTF container version " + std::to_string(u32(4)) + " (only 2 is supported)");
  if (u32(8) > bytes.size())
    throw InputError(file, "header", "file is truncated: the header says " + std::to_string(u32(8)) +
                                         " bytes, the file has " + std::to_string(bytes.size()));
  const uint32_t jsonLength = u32(12);
  if (u32(16) != 0x4E4F534A) throw InputError(file, "byte 16", "the first chunk is not JSON");
  if (size_t(20) + jsonLength > bytes.size())
    throw InputError(file, "byte 12", "file is truncated inside the JSON chunk");
  if (jsonLength % 4 != 0) throw InputError(file, "byte 12", "JSON chunk length " + std::to_string(jsonLength) + " is not a multiple of 4");
  // The BIN chunk, if any, must lie inside the file (tinygltf reports an oversized one as
  // "not aligned to a 4-byte boundary").
  const size_t bin = 20 + size_t(jsonLength);
  if (bin + 8 <= bytes.size()) {
    const uint32_t binLength = u32(bin);
    if (bin + 8 + size_t(binLength) > bytes.size())
      throw InputError(file, "byte " + std::to_string(bin), "the BIN chunk of " + std::to_string(binLength) +
                                                              " bytes runs past the end of the file (" +
                                                              std::to_string(bytes.size()) + " bytes)");
  }
  return bytes.substr(20, jsonLength);
}

std::string readFile(const std::string& path) { return readWholeFile(path, "glTF file", kMeshStreamCap); }

// tinygltf reads a glTF's buffers and images through this: checked and capped like the file.
bool readReferencedFile(std::vector<unsigned char>* out, std::string* err, const std::string& path, void*) {
  try {
    const std::string bytes = readWholeFile(path, "glTF buffer or image", kMeshStreamCap);
    out->assign(bytes.begin(), bytes.end());
    return true;
  } catch (const InputError& e) {
    if (err) *err += std::string(e.what()) + "\n";
    return false;
  }
}

// Keeps images encoded: tinygltf would otherwise decode every image of the file.
bool keepEncoded(tinygltf::Image* image, const int, std::string*, std::string*, int, int,
                 const unsigned char* bytes, int size, void*) {
  image->image.assign(bytes, bytes + size);
  return true;
}

constexpr int kMaxNodeDepth = 1000;

class Reader {
 public:
  Reader(const tinygltf::Model& m, GltfModel& out) : m_model(m), m_out(out) {}

  [[noreturn]] void fail(const std::string& where, const std::string& what) const {
    throw InputError(m_out.path, where, what);
  }
  void warnOnce(const std::string& what) {
    if (m_warned.insert(what).second) m_out.warnings.push_back(what);
  }

  // Element `k` of an accessor, as doubles, after a bounds check of the whole accessor.
  struct View {
    const unsigned char* data = nullptr;
    size_t stride = 0, count = 0;
    int componentType = 0, components = 0;
    bool normalized = false;
    double get(size_t k, int c) const {
      const unsigned char* p = data + k * stride;
      switch (componentType) {
        case TINYGLTF_COMPONENT_TYPE_FLOAT: { float v; std::memcpy(&v, p + 4 * c, 4); return v; }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return normalized ? p[c] / 255.0 : p[c];
        case TINYGLTF_COMPONENT_TYPE_BYTE: { const double v = int8_t(p[c]); return normalized ? std::max(v / 127.0, -1.0) : v; }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: { uint16_t v; std::memcpy(&v, p + 2 * c, 2); return normalized ? v / 65535.0 : v; }
        case TINYGLTF_COMPONENT_TYPE_SHORT: { int16_t v; std::memcpy(&v, p + 2 * c, 2); return normalized ? std::max(v / 32767.0, -1.0) : v; }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: { uint32_t v; std::memcpy(&v, p + 4 * c, 4); return v; }
      }
      return 0;
    }
  };

  View accessor(int index, const std::string& where, std::initializer_list<int> types, int components) {
    if (index < 0 || size_t(index) >= m_model.accessors.size())
      fail(where, "accessor " + std::to_string(index) + " does not exist (" +
                      std::to_string(m_model.accessors.size()) + " accessors)");
    const tinygltf::Accessor& a = m_model.accessors[index];
    const std::string at = "/accessors/" + std::to_string(index);
    if (a.sparse.isSparse) fail(at, "sparse accessors are not supported");
    bool typeOk = false;
    for (int t : types) typeOk |= a.componentType == t;
    if (!typeOk) fail(at + "/componentType", "component type " + std::to_string(a.componentType) + " is not allowed here");
    if (tinygltf::GetNumComponentsInType(uint32_t(a.type)) != components)
      fail(at + "/type", "expected " + std::to_string(components) + " components per element");
    if (a.bufferView < 0 || size_t(a.bufferView) >= m_model.bufferViews.size())
      fail(at + "/bufferView", "buffer view " + std::to_string(a.bufferView) + " does not exist");
    const tinygltf::BufferView& bv = m_model.bufferViews[a.bufferView];
    const std::string bvAt = "/bufferViews/" + std::to_string(a.bufferView);
    if (bv.buffer < 0 || size_t(bv.buffer) >= m_model.buffers.size())
      fail(bvAt + "/buffer", "buffer " + std::to_string(bv.buffer) + " does not exist");
    const size_t bufferSize = m_model.buffers[bv.buffer].data.size();
    if (bv.byteOffset > bufferSize || bv.byteLength > bufferSize - bv.byteOffset)
      fail(bvAt, "bytes " + std::to_string(bv.byteOffset) + "+" + std::to_string(bv.byteLength) +
                     " lie outside buffer " + std::to_string(bv.buffer) + " of " + std::to_string(bufferSize) + " bytes");
    const int stride = a.ByteStride(bv);
    if (stride <= 0) fail(bvAt + "/byteStride", "invalid byte stride");
    const size_t element = size_t(tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType))) * components;
    // In this order, nothing can wrap: (count - 1) * stride is compared by division.
    if (a.count > 0 && (a.byteOffset > bv.byteLength || element > bv.byteLength - a.byteOffset ||
                        (a.count - 1) > (bv.byteLength - a.byteOffset - element) / size_t(stride)))
      fail(at, std::to_string(a.count) + " elements do not fit in buffer view " + std::to_string(a.bufferView));
    View v;
    v.data = m_model.buffers[bv.buffer].data.data() + bv.byteOffset + a.byteOffset;
    v.stride = size_t(stride);
    v.count = a.count;
    v.componentType = a.componentType;
    v.components = components;
    v.normalized = a.normalized;
    return v;
  }

  TriangleMesh primitive(int meshIndex, int primIndex, bool& skipped) {
    const tinygltf::Primitive& p = m_model.meshes[meshIndex].primitives[primIndex];
    const std::string at = "/meshes/" + std::to_string(meshIndex) + "/primitives/" + std::to_string(primIndex);
    TriangleMesh mesh;
    skipped = false;
    const int mode = p.mode < 0 ? TINYGLTF_MODE_TRIANGLES : p.mode;
    if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP && mode != TINYGLTF_MODE_TRIANGLE_FAN) {
      if (mode > TINYGLTF_MODE_TRIANGLE_FAN) fail(at + "/mode", "unknown primitive mode " + std::to_string(mode));
      warnOnce("point and line primitives are not rendered (first at " + at + ")");
      skipped = true;
      return mesh;
    }
    if (!p.targets.empty()) warnOnce("morph targets are not supported: meshes keep their base shape");
    auto attribute = [&](const char* name) {
      auto it = p.attributes.find(name);
      return it == p.attributes.end() ? -1 : it->second;
    };
    const int posIndex = attribute("POSITION");
    if (posIndex < 0) fail(at + "/attributes", "a triangle primitive needs POSITION");
    const View pos = accessor(posIndex, at + "/attributes/POSITION", {TINYGLTF_COMPONENT_TYPE_FLOAT}, 3);
    mesh.positions.resize(pos.count);
    for (size_t k = 0; k < pos.count; ++k) {
      mesh.positions[k] = Vec3f{float(pos.get(k, 0)), float(pos.get(k, 1)), float(pos.get(k, 2))};
      if (!isFinite(mesh.positions[k]))
        fail("/accessors/" + std::to_string(posIndex), "vertex " + std::to_string(k) + " is not finite");
    }
    if (int n = attribute("NORMAL"); n >= 0) {
      const View nv = accessor(n, at + "/attributes/NORMAL", {TINYGLTF_COMPONENT_TYPE_FLOAT}, 3);
      if (nv.count != pos.count) fail(at + "/attributes/NORMAL", "count differs from POSITION");
      mesh.normals.resize(nv.count);
      for (size_t k = 0; k < nv.count; ++k) {
        const Vec3f nk{float(nv.get(k, 0)), float(nv.get(k, 1)), float(nv.get(k, 2))};
        const float len = length(nk);
        // A zero or broken normal falls back to the flat one at shading time.
        mesh.normals[k] = len > 0 && std::isfinite(len) ? nk / len : Vec3f{0, 0, 0};
      }
    }
    if (int t = attribute("TEXCOORD_0"); t >= 0) {
      const View tv = accessor(t, at + "/attributes/TEXCOORD_0",
                               {TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE,
                                TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT}, 2);
      if (tv.count != pos.count) fail(at + "/attributes/TEXCOORD_0", "count differs from POSITION");
      mesh.uvs.resize(tv.count);
      for (size_t k = 0; k < tv.count; ++k) mesh.uvs[k] = {float(tv.get(k, 0)), float(tv.get(k, 1))};
    }
    std::vector<uint32_t> order;
    if (p.indices >= 0) {
      const View iv = accessor(p.indices, at + "/indices",
                               {TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE, TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT,
                                TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT}, 1);
      order.resize(iv.count);
      for (size_t k = 0; k < iv.count; ++k) {
        const double v = iv.get(k, 0);
        if (v >= double(pos.count))
          fail("/accessors/" + std::to_string(p.indices),
               "index " + std::to_string(uint64_t(v)) + " (element " + std::to_string(k) +
                   ") is out of range: the primitive has " + std::to_string(pos.count) + " vertices");
        order[k] = uint32_t(v);
      }
    } else {
      order.resize(pos.count);
      for (size_t k = 0; k < pos.count; ++k) order[k] = uint32_t(k);
    }
    if (mode == TINYGLTF_MODE_TRIANGLES) {
      mesh.indices.assign(order.begin(), order.begin() + order.size() / 3 * 3);
    } else if (mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
      // Every other triangle of a strip is flipped back to counter-clockwise (glTF 3.7.2.1).
      for (size_t k = 2; k < order.size(); ++k)
        if (k % 2 == 0) mesh.indices.insert(mesh.indices.end(), {order[k - 2], order[k - 1], order[k]});
        else mesh.indices.insert(mesh.indices.end(), {order[k - 1], order[k - 2], order[k]});
    } else {
      for (size_t k = 2; k < order.size(); ++k)
        mesh.indices.insert(mesh.indices.end(), {order[0], order[k - 1], order[k]});
    }
    if (p.material >= 0 && size_t(p.material) >= m_model.materials.size())
      fail(at + "/material", "material " + std::to_string(p.material) + " does not exist");
    mesh.material = p.material;
    return mesh;
  }

  GltfTextureRef texture(const tinygltf::TextureInfo& info, int texCoord, const std::string& at) {
    GltfTextureRef ref;
    if (info.index < 0) return ref;
    if (size_t(info.index) >= m_model.textures.size())
      fail(at + "/index", "texture " + std::to_string(info.index) + " does not exist");
    if (texCoord != 0) warnOnce("only TEXCOORD_0 is supported; textures on other coordinate sets use set 0");
    if (!info.extensions.empty()) warnOnce("texture extensions (" + info.extensions.begin()->first + ") are ignored");
    ref.texture = info.index;
    return ref;
  }

  GltfMaterial material(int index) {
    const tinygltf::Material& m = m_model.materials[index];
    const std::string at = "/materials/" + std::to_string(index);
    GltfMaterial g;
    g.name = m.name;
    const auto& pbr = m.pbrMetallicRoughness;
    if (pbr.baseColorFactor.size() >= 3)
      g.baseColor = {float(pbr.baseColorFactor[0]), float(pbr.baseColorFactor[1]), float(pbr.baseColorFactor[2])};
    g.metallic = float(std::clamp(pbr.metallicFactor, 0.0, 1.0));
    g.roughness = float(std::clamp(pbr.roughnessFactor, 0.0, 1.0));
    if (m.emissiveFactor.size() == 3)
      g.emissive = {float(m.emissiveFactor[0]), float(m.emissiveFactor[1]), float(m.emissiveFactor[2])};
    g.doubleSided = m.doubleSided;
    g.baseColorTexture = texture(pbr.baseColorTexture, pbr.baseColorTexture.texCoord, at + "/pbrMetallicRoughness/baseColorTexture");
    g.metallicRoughnessTexture = texture(pbr.metallicRoughnessTexture, pbr.metallicRoughnessTexture.texCoord,
                                         at + "/pbrMetallicRoughness/metallicRoughnessTexture");
    g.emissiveTexture = texture(m.emissiveTexture, m.emissiveTexture.texCoord, at + "/emissiveTexture");
    if (m.normalTexture.index >= 0) {
      tinygltf::TextureInfo info;
      info.index = m.normalTexture.index;
      g.normalTexture = texture(info, m.normalTexture.texCoord, at + "/normalTexture");
      g.normalScale = float(m.normalTexture.scale);
    }
    if (m.occlusionTexture.index >= 0) warnOnce("occlusion textures are ignored (a path tracer computes occlusion)");
    if (m.alphaMode != "OPAQUE") warnOnce("alphaMode " + m.alphaMode + " is not supported: materials are opaque");
    for (const auto& [name, value] : m.extensions) {
      if (name == "KHR_materials_emissive_strength") {
        if (value.Has("emissiveStrength")) g.emissive = g.emissive * float(value.Get("emissiveStrength").GetNumberAsDouble());
      } else {
        warnOnce("material extension " + name + " is not supported and is ignored");
      }
    }
    return g;
  }

  static Transform nodeTransform(const tinygltf::Node& n) {
    if (n.matrix.size() == 16) {  // column-major in glTF
      double rows[12];
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 4; ++j) rows[i * 4 + j] = n.matrix[j * 4 + i];
      return Transform::fromRows(rows);
    }
    Transform t;
    if (n.scale.size() == 3) t = Transform::scale({n.scale[0], n.scale[1], n.scale[2]});
    if (n.rotation.size() == 4) t = Transform::quaternion(n.rotation[0], n.rotation[1], n.rotation[2], n.rotation[3]) * t;
    if (n.translation.size() == 3) t = Transform::translate({n.translation[0], n.translation[1], n.translation[2]}) * t;
    return t;
  }

  void visit(int index, const Transform& parent, std::vector<char>& onPath, std::vector<char>& seen,
             const std::string& from, int depth = 0) {
    if (index < 0 || size_t(index) >= m_model.nodes.size())
      fail(from, "node " + std::to_string(index) + " does not exist");
    const std::string at = "/nodes/" + std::to_string(index);
    // The visit recurses: a chain of nodes deeper than any real model is refused.
    if (depth > kMaxNodeDepth) fail(at, "the node hierarchy is more than " + std::to_string(kMaxNodeDepth) + " levels deep");
    if (onPath[index]) fail(at + "/children", "the node hierarchy has a cycle through node " + std::to_string(index));
    if (seen[index]) fail(at, "node " + std::to_string(index) + " has more than one parent");
    onPath[index] = seen[index] = 1;
    const tinygltf::Node& n = m_model.nodes[index];
    if ((n.matrix.size() != 0 && n.matrix.size() != 16) || (n.scale.size() != 0 && n.scale.size() != 3) ||
        (n.rotation.size() != 0 && n.rotation.size() != 4) || (n.translation.size() != 0 && n.translation.size() != 3))
      fail(at, "matrix, translation, rotation or scale has the wrong number of elements");
    const Transform t = parent * nodeTransform(n);
    const std::string label = at + (n.name.empty() ? "" : " (" + n.name + ")");
    if (n.skin >= 0) warnOnce("skins are not supported: skinned meshes are shown in their bind pose");
    if (n.mesh >= 0) {
      if (size_t(n.mesh) >= m_model.meshes.size()) fail(at + "/mesh", "mesh " + std::to_string(n.mesh) + " does not exist");
      if (!t.isFiniteInvertible()) fail(at, "the node's transform is not invertible");
      m_out.instances.push_back({n.mesh, t, label});
    }
    if (n.camera >= 0) {
      if (size_t(n.camera) >= m_model.cameras.size()) fail(at + "/camera", "camera " + std::to_string(n.camera) + " does not exist");
      const tinygltf::Camera& c = m_model.cameras[n.camera];
      if (c.type != "perspective") {
        warnOnce("orthographic cameras are not supported (camera " + std::to_string(n.camera) + ")");
      } else {
        GltfCamera cam;
        cam.name = c.name.empty() ? "camera " + std::to_string(n.camera) : c.name;
        cam.desc.position = t.point({0, 0, 0});
        cam.desc.lookAt = cam.desc.position + normalize(t.vector({0, 0, -1}));
        cam.desc.up = normalize(t.vector({0, 1, 0}));
        cam.desc.fov = c.perspective.yfov * 180 / M_PI;
        if (!(cam.desc.fov > 0 && cam.desc.fov < 179)) fail("/cameras/" + std::to_string(n.camera) + "/perspective/yfov", "field of view out of range");
        m_out.cameras.push_back(cam);
      }
    }
    auto light = n.extensions.find("KHR_lights_punctual");
    if (light != n.extensions.end() && light->second.Has("light")) {
      const int li = light->second.Get("light").GetNumberAsInt();
      if (li < 0 || size_t(li) >= m_model.lights.size())
        fail(at + "/extensions/KHR_lights_punctual/light", "light " + std::to_string(li) + " does not exist");
      const tinygltf::Light& gl = m_model.lights[li];
      LightDesc l;
      l.where = m_out.path + " " + label;
      Vec3d color{1, 1, 1};
      if (gl.color.size() == 3) color = {gl.color[0], gl.color[1], gl.color[2]};
      const Vec3d power = color * gl.intensity;
      l.position = t.point({0, 0, 0});
      l.direction = normalize(t.vector({0, 0, -1}));
      if (gl.type == "point" || gl.type == "spot") {
        l.type = gl.type == "point" ? LightType::Point : LightType::Spot;
        l.intensity = power;  // candela taken as W/sr
        l.outerAngle = gl.spot.outerConeAngle * 180 / M_PI;
        l.innerAngle = std::min(gl.spot.innerConeAngle * 180 / M_PI, l.outerAngle);
      } else if (gl.type == "directional") {
        l.type = LightType::Directional;
        l.irradiance = power;  // lux taken as W/m^2
      } else {
        fail("/extensions/KHR_lights_punctual/lights/" + std::to_string(li) + "/type", "unknown light type '" + gl.type + "'");
      }
      if (gl.range > 0) warnOnce("light range is ignored (lights fall off with the inverse square law)");
      m_out.lights.push_back(l);
    }
    for (int child : n.children) visit(child, t, onPath, seen, at + "/children", depth + 1);
    onPath[index] = 0;
  }

  void read() {
    static const std::set<std::string> supported = {"KHR_lights_punctual", "KHR_materials_emissive_strength"};
    for (size_t i = 0; i < m_model.extensionsRequired.size(); ++i)
      if (!supported.count(m_model.extensionsRequired[i]))
        fail("/extensionsRequired/" + std::to_string(i),
             "required extension " + m_model.extensionsRequired[i] + " is not supported");
    for (const std::string& e : m_model.extensionsUsed)
      if (!supported.count(e)) warnOnce("extension " + e + " is not supported and is ignored");
    if (!m_model.animations.empty()) warnOnce("animations are ignored: the file is rendered in its rest pose");

    m_out.meshes.resize(m_model.meshes.size());
    for (size_t i = 0; i < m_model.meshes.size(); ++i) {
      m_out.meshNames.push_back(m_model.meshes[i].name);
      for (size_t k = 0; k < m_model.meshes[i].primitives.size(); ++k) {
        bool skipped;
        TriangleMesh prim = primitive(int(i), int(k), skipped);
        if (!skipped && prim.triangleCount() > 0) m_out.meshes[i].push_back(std::move(prim));
      }
    }
    for (size_t i = 0; i < m_model.materials.size(); ++i) m_out.materials.push_back(material(int(i)));
    for (size_t i = 0; i < m_model.textures.size(); ++i) {
      const tinygltf::Texture& t = m_model.textures[i];
      GltfTexture g;
      g.image = t.source;
      if (t.sampler >= 0) {
        if (size_t(t.sampler) >= m_model.samplers.size())
          fail("/textures/" + std::to_string(i) + "/sampler", "sampler " + std::to_string(t.sampler) + " does not exist");
        const tinygltf::Sampler& s = m_model.samplers[t.sampler];
        auto wrap = [](int mode) {
          return mode == TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE ? TextureWrap::Clamp
                 : mode == TINYGLTF_TEXTURE_WRAP_MIRRORED_REPEAT ? TextureWrap::Mirror : TextureWrap::Repeat;
        };
        g.wrapS = wrap(s.wrapS);
        g.wrapT = wrap(s.wrapT);
        g.nearest = s.magFilter == TINYGLTF_TEXTURE_FILTER_NEAREST;
      }
      m_out.textures.push_back(g);
    }
    // An image is checked when a material that uses it is built (the file may list unused ones).
    for (size_t i = 0; i < m_model.images.size(); ++i) {
      const tinygltf::Image& im = m_model.images[i];
      m_out.images.push_back({im.uri.empty() ? "/images/" + std::to_string(i) : im.uri, im.image});
    }

    const int sceneIndex = m_model.defaultScene >= 0 ? m_model.defaultScene : 0;
    std::vector<char> onPath(m_model.nodes.size(), 0), seen(m_model.nodes.size(), 0);
    if (!m_model.scenes.empty()) {
      if (size_t(sceneIndex) >= m_model.scenes.size()) fail("/scene", "scene " + std::to_string(sceneIndex) + " does not exist");
      for (int root : m_model.scenes[sceneIndex].nodes)
        visit(root, Transform(), onPath, seen, "/scenes/" + std::to_string(sceneIndex) + "/nodes");
    } else {
      // No scene: every node that is nobody's child is a root (glTF 3.5.1 leaves this to us).
      std::vector<char> isChild(m_model.nodes.size(), 0);
      for (const tinygltf::Node& n : m_model.nodes)
        for (int c : n.children)
          if (c >= 0 && size_t(c) < isChild.size()) isChild[c] = 1;
      for (size_t i = 0; i < m_model.nodes.size(); ++i)
        if (!isChild[i]) visit(int(i), Transform(), onPath, seen, "/nodes");
      if (m_model.nodes.size() && std::find(isChild.begin(), isChild.end(), 0) == isChild.end())
        fail("/nodes", "every node is a child of another: the node hierarchy has a cycle");
    }
  }

 private:
  const tinygltf::Model& m_model;
  GltfModel& m_out;
  std::set<std::string> m_warned;
};

}  // namespace

GltfModel loadGltf(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(path, "", "glTF file not found");
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  if (ext != ".gltf" && ext != ".glb") throw InputError(path, "", "unknown mesh extension (supported: .gltf, .glb, .obj)");
  const std::string bytes = readFile(path);
  const bool binary = ext == ".glb" || bytes.compare(0, 4, "glTF") == 0;
  const std::string jsonText = binary ? glbJson(bytes, path) : bytes;

  checkJsonNesting(jsonText, path);  // tinygltf walks extras and extensions recursively
  Json root;
  try {
    root = Json::parse(jsonText);
  } catch (const Json::parse_error& e) {
    throw InputError(path, "byte " + std::to_string(e.byte), "JSON syntax error");
  } catch (const Json::exception& e) {
    throwJsonError(path, e.what());
  }
  if (!root.is_object()) throw InputError(path, "/", "expected a JSON object");
  for (const Rule& rule : kRules) checkRule(root, rule.path, 0, "", rule.kind, path);
  // External files are checked here, where the JSON path is known (tinygltf would read a
  // directory as a file of undefined size).
  for (const char* list : {"buffers", "images"}) {
    if (!root.contains(list)) continue;
    for (size_t i = 0; i < root[list].size(); ++i) {
      const Json& item = root[list][i];
      if (!item.contains("uri")) continue;
      const std::string uri = item["uri"].get<std::string>();
      const std::string at = "/" + std::string(list) + "/" + std::to_string(i) + "/uri";
      if (uri.rfind("data:", 0) == 0) {
        // tinygltf calls a data URI it cannot decode "File not found": say what is wrong.
        const size_t comma = uri.find(',');
        if (comma == std::string::npos || uri.rfind(";base64", comma) == std::string::npos)
          throw InputError(path, at, "a data URI must be base64 (data:...;base64,...)");
        const std::string payload = uri.substr(comma + 1);
        const bool base64 = payload.size() % 4 == 0 && std::all_of(payload.begin(), payload.end(), [](char c) {
          return std::isalnum(static_cast<unsigned char>(c)) || c == '+' || c == '/' || c == '=';
        });
        if (!base64) throw InputError(path, at, "the data URI's payload is not valid base64");
        continue;
      }
      if (uri.find('%') != std::string::npos) continue;  // percent-encoded: tinygltf decodes it
      const fs::path file = fs::path(path).parent_path() / uri;
      std::error_code ec;
      if (fs::is_directory(file, ec)) throw InputError(path, at, "'" + uri + "' is a directory");
      if (!fs::exists(file, ec)) throw InputError(path, at, "'" + uri + "': file not found");
      try {
        checkInputFile(file.string(), "glTF buffer or image");
      } catch (const InputError& e) {
        throw InputError(path, at, e.what());
      }
    }
  }

  tinygltf::TinyGLTF loader;
  loader.SetImageLoader(keepEncoded, nullptr);
  loader.SetFsCallbacks({&tinygltf::FileExists, &tinygltf::ExpandFilePath, &readReferencedFile, &tinygltf::WriteWholeFile, nullptr});
  tinygltf::Model model;
  std::string err, warn;
  const std::string baseDir = fs::path(path).parent_path().string();
  const bool ok = binary ? loader.LoadBinaryFromMemory(&model, &err, &warn,
                                                      reinterpret_cast<const unsigned char*>(bytes.data()),
                                                      unsigned(bytes.size()), baseDir)
                         : loader.LoadASCIIFromString(&model, &err, &warn, bytes.data(), unsigned(bytes.size()),
                                                      baseDir);
  if (!ok || !err.empty()) throw InputError(path, "", oneLine(err.empty() ? "cannot read the glTF file" : err));
  // Buffers shorter than they claim would be read past their end.
  for (size_t i = 0; i < model.buffers.size(); ++i) {
    auto j = root["buffers"][i].find("byteLength");
    if (j != root["buffers"][i].end() && j->get<long long>() > (long long)model.buffers[i].data.size())
      throw InputError(path, "/buffers/" + std::to_string(i),
                       "buffer holds " + std::to_string(model.buffers[i].data.size()) + " bytes, byteLength says " +
                           std::to_string(j->get<long long>()));
  }

  GltfModel out;
  out.path = path;
  Reader(model, out).read();
  return out;
}

}  // namespace iso

namespace iso {

void saveGltfMesh(const std::string& path, const GltfMeshOut& mesh) {
  const std::filesystem::path out(path);
  const std::string ext = out.extension().string();
  if (ext != ".glb" && ext != ".gltf") throw InputError(path, "", "the mesh output must be .glb or .gltf");
  if (out.has_parent_path() && !std::filesystem::is_directory(out.parent_path()))
    throw InputError(path, "", "output directory does not exist");
  if (mesh.indices.empty()) throw InputError(path, "", "no triangles to write");

  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "isotrace mesh";
  tinygltf::Buffer buffer;
  auto append = [&](const void* data, size_t bytes) {
    const size_t offset = buffer.data.size();
    const auto* p = static_cast<const unsigned char*>(data);
    buffer.data.insert(buffer.data.end(), p, p + bytes);
    buffer.data.resize((buffer.data.size() + 3) & ~size_t(3));  // 4-byte alignment
    return offset;
  };
  auto view = [&](const void* data, size_t bytes, int target) {
    tinygltf::BufferView v;
    v.buffer = 0;
    v.byteOffset = append(data, bytes);
    v.byteLength = bytes;
    v.target = target;
    model.bufferViews.push_back(v);
    return int(model.bufferViews.size() - 1);
  };
  auto accessor = [&](int bufferView, int componentType, int type, size_t count) {
    tinygltf::Accessor a;
    a.bufferView = bufferView;
    a.componentType = componentType;
    a.type = type;
    a.count = count;
    model.accessors.push_back(a);
    return int(model.accessors.size() - 1);
  };
  const size_t n = mesh.positions.size();
  const int positions = accessor(view(mesh.positions.data(), n * sizeof(Vec3f), TINYGLTF_TARGET_ARRAY_BUFFER),
                                 TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, n);
  Vec3f lo = mesh.positions[0], hi = mesh.positions[0];
  for (const Vec3f& p : mesh.positions) { lo = min(lo, p); hi = max(hi, p); }
  model.accessors[positions].minValues = {lo.x, lo.y, lo.z};  // required for POSITION
  model.accessors[positions].maxValues = {hi.x, hi.y, hi.z};
  const int normals = accessor(view(mesh.normals.data(), n * sizeof(Vec3f), TINYGLTF_TARGET_ARRAY_BUFFER),
                               TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, n);
  const int colors = mesh.colors.size() == n ? accessor(view(mesh.colors.data(), n * sizeof(Vec3f), TINYGLTF_TARGET_ARRAY_BUFFER),
                                                       TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, n)
                                              : -1;
  const int indices = accessor(view(mesh.indices.data(), mesh.indices.size() * sizeof(uint32_t),
                                    TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER),
                               TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT, TINYGLTF_TYPE_SCALAR, mesh.indices.size());
  model.buffers.push_back(std::move(buffer));

  tinygltf::Material material;
  material.name = mesh.name;
  material.pbrMetallicRoughness.baseColorFactor = {mesh.color.x, mesh.color.y, mesh.color.z, 1.0};
  material.pbrMetallicRoughness.metallicFactor = mesh.metallic;
  material.pbrMetallicRoughness.roughnessFactor = mesh.roughness;
  model.materials.push_back(material);

  tinygltf::Primitive primitive;
  primitive.attributes["POSITION"] = positions;
  primitive.attributes["NORMAL"] = normals;
  if (colors >= 0) primitive.attributes["COLOR_0"] = colors;  // (glTF multiplies them with the base colour)
  primitive.indices = indices;
  primitive.material = 0;
  primitive.mode = TINYGLTF_MODE_TRIANGLES;
  tinygltf::Mesh m;
  m.name = mesh.name;
  m.primitives.push_back(primitive);
  model.meshes.push_back(m);
  tinygltf::Node node;
  node.mesh = 0;
  node.name = mesh.name;
  model.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.nodes.push_back(0);
  model.scenes.push_back(scene);
  model.defaultScene = 0;

  const std::string temp = path + ".partial" + ext;
  tinygltf::TinyGLTF writer;
  const bool binary = ext == ".glb";
  if (!writer.WriteGltfSceneToFile(&model, temp, true, true, !binary, binary)) {
    std::remove(temp.c_str());
    throw InputError(path, "", "cannot write");
  }
  std::error_code error;
  std::filesystem::rename(temp, path, error);
  if (error) {
    std::remove(temp.c_str());
    throw InputError(path, "", "cannot write: " + error.message());
  }
}

}  // namespace iso
