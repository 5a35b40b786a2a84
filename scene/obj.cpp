// Wavefront OBJ (+ MTL) through tinyobjloader, into the same model struct as glTF; the only
// file that sees tinyobjloader. What is read: docs/scene-format.md, "OBJ meshes".
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "scene/gltf.h"
#include "volume/input_error.h"
#include "volume/input_file.h"

namespace iso {
namespace {

namespace fs = std::filesystem;

// tinyobjloader reports problems as lines "filename: line N: ..." or plain text; the first
// line is enough to say what is wrong.
std::string firstLine(const std::string& text) {
  std::string s = text.substr(0, text.find('\n'));
  while (!s.empty() && (s.back() == '\r' || s.back() == ' ')) s.pop_back();
  return s;
}

Vec3f rgb(const tinyobj::real_t c[3]) { return {float(c[0]), float(c[1]), float(c[2])}; }

}  // namespace

GltfModel loadObj(const std::string& path) {
  std::error_code ec;
  // tinyobjloader reads the OBJ and its MTL files line by line, however long: they must be
  // regular files (a pipe or a device is refused by name before it reads a byte).
  checkInputFile(path, "OBJ file", false);
  {
    std::ifstream obj(path);
    for (std::string line; std::getline(obj, line);) {
      const size_t at = line.find_first_not_of(" \t");
      if (at == std::string::npos || line.compare(at, 7, "mtllib ") != 0) continue;
      std::istringstream names(line.substr(at + 7));
      for (std::string name; names >> name;) {
        const fs::path mtl = fs::path(path).parent_path() / name;
        if (fs::exists(mtl, ec)) checkInputFile(mtl.string(), "MTL file", false);
      }
    }
  }
  tinyobj::ObjReaderConfig config;
  config.triangulate = true;
  config.vertex_color = false;
  config.mtl_search_path = fs::path(path).parent_path().string();
  tinyobj::ObjReader reader;
  if (!reader.ParseFromFile(path, config)) {
    const std::string why = firstLine(reader.Error());
    throw InputError(path, "", why.empty() ? "cannot read the OBJ file" : why);
  }
  GltfModel model;
  model.path = path;
  if (!reader.Warning().empty()) model.warnings.push_back(firstLine(reader.Warning()));
  const tinyobj::attrib_t& attrib = reader.GetAttrib();
  const size_t vertexCount = attrib.vertices.size() / 3, normalCount = attrib.normals.size() / 3,
               uvCount = attrib.texcoords.size() / 2;
  for (size_t i = 0; i < attrib.vertices.size(); ++i)
    if (!std::isfinite(attrib.vertices[i]) || std::fabs(attrib.vertices[i]) > 1e15f)
      throw InputError(path, "vertex " + std::to_string(i / 3 + 1), "coordinate is not finite or beyond 1e15");

  // Materials: Kd is a Lambertian colour, Ke the emission. The Cornell box OBJ that
  // tinyobjloader ships gives its lamp as Ka 20 (an ambient colour above 1 cannot be a
  // reflectance): without Ke, such an ambient colour is read as emission, with a warning.
  const std::vector<tinyobj::material_t>& mtl = reader.GetMaterials();
  std::set<std::string> ignored;
  for (const tinyobj::material_t& m : mtl) {
    GltfMaterial g;
    g.name = m.name;
    g.type = MaterialType::Diffuse;
    g.baseColor = rgb(m.diffuse);
    g.emissive = rgb(m.emission);
    const Vec3f ka = rgb(m.ambient);
    if (g.emissive == Vec3f{0, 0, 0} && std::max({ka.x, ka.y, ka.z}) > 1) {
      g.emissive = ka;
      model.warnings.push_back("material '" + m.name + "': Ka above 1 without Ke, read as emission");
    }
    for (float c : {g.baseColor.x, g.baseColor.y, g.baseColor.z, g.emissive.x, g.emissive.y, g.emissive.z})
      if (!std::isfinite(c) || c < 0)
        throw InputError(path, "material '" + m.name + "'", "colours must be finite and non-negative");
    if (!m.diffuse_texname.empty()) {
      const fs::path file = fs::path(config.mtl_search_path) / m.diffuse_texname;
      if (!fs::is_regular_file(file, ec))
        throw InputError(path, "material '" + m.name + "'", "map_Kd '" + m.diffuse_texname + "': file not found");
      std::ifstream in(file, std::ios::binary);
      GltfImage image;
      image.name = m.diffuse_texname;
      image.encoded.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
      model.images.push_back(std::move(image));
      GltfTexture texture;
      texture.image = int(model.images.size() - 1);
      model.textures.push_back(texture);
      g.baseColorTexture.texture = int(model.textures.size() - 1);
    }
    if (m.dissolve < 1 || m.illum > 2 || m.specular[0] > 0 || m.specular[1] > 0 || m.specular[2] > 0)
      ignored.insert(m.name);
    g.doubleSided = true;  // OBJ has no notion of a back face
    model.materials.push_back(g);
  }
  if (!ignored.empty()) {
    std::string names;
    for (const std::string& n : ignored) names += (names.empty() ? "'" : ", '") + n + "'";
    model.warnings.push_back("specular, transparency and illumination models are not read (materials " + names +
                             "): they render as Lambertian Kd");
  }

  // One mesh; a primitive per material (faces keep their shape's order), vertices unshared.
  std::map<int, size_t> primitiveOf;
  std::vector<TriangleMesh> primitives;
  for (const tinyobj::shape_t& shape : reader.GetShapes()) {
    const tinyobj::mesh_t& m = shape.mesh;
    size_t at = 0;
    for (size_t f = 0; f < m.num_face_vertices.size(); ++f) {
      const size_t n = m.num_face_vertices[f];
      const std::string where = (shape.name.empty() ? "" : "shape '" + shape.name + "' ") + "face " + std::to_string(f + 1);
      if (n != 3) throw InputError(path, where, "not a triangle after triangulation");
      const int material = f < m.material_ids.size() ? m.material_ids[f] : -1;
      if (material >= int(mtl.size())) throw InputError(path, where, "material index out of range");
      auto [it, added] = primitiveOf.emplace(material, primitives.size());
      if (added) {
        primitives.emplace_back();
        primitives.back().material = material;
      }
      TriangleMesh& prim = primitives[it->second];
      bool normals = true, uvs = true;
      for (size_t k = 0; k < 3; ++k) {
        const tinyobj::index_t& idx = m.indices[at + k];
        normals = normals && idx.normal_index >= 0;
        uvs = uvs && idx.texcoord_index >= 0;
      }
      for (size_t k = 0; k < 3; ++k) {
        const tinyobj::index_t& idx = m.indices[at + k];
        if (idx.vertex_index < 0 || size_t(idx.vertex_index) >= vertexCount)
          throw InputError(path, where, "vertex index out of range");
        if (normals && size_t(idx.normal_index) >= normalCount) throw InputError(path, where, "normal index out of range");
        if (uvs && size_t(idx.texcoord_index) >= uvCount) throw InputError(path, where, "texture index out of range");
        const float* v = &attrib.vertices[3 * size_t(idx.vertex_index)];
        prim.positions.push_back({v[0], v[1], v[2]});
        if (normals) {
          const float* nn = &attrib.normals[3 * size_t(idx.normal_index)];
          const Vec3f nv{nn[0], nn[1], nn[2]};
          const float len = length(nv);
          prim.normals.push_back(len > 0 && std::isfinite(len) ? nv / len : Vec3f{0, 0, 0});
        }
        if (uvs) {
          const float* t = &attrib.texcoords[2 * size_t(idx.texcoord_index)];
          prim.uvs.push_back({t[0], 1 - t[1]});  // OBJ's v grows upwards, the image's rows downwards
        }
        prim.indices.push_back(uint32_t(prim.positions.size() - 1));
      }
      at += n;
    }
  }
  // A primitive keeps per-vertex normals and UVs only if every face gave them.
  for (TriangleMesh& prim : primitives) {
    if (prim.normals.size() != prim.positions.size()) prim.normals.clear();
    if (prim.uvs.size() != prim.positions.size()) prim.uvs.clear();
  }
  if (primitives.empty()) throw InputError(path, "", "no faces");
  model.meshes.push_back(std::move(primitives));
  model.meshNames.push_back(fs::path(path).stem().string());
  model.instances.push_back({0, Transform(), "OBJ"});
  return model;
}

}  // namespace iso
