#pragma once
// glTF 2.0 import (.gltf with external or embedded buffers, .glb) into plain structs; the
// only file that sees tinygltf is gltf.cpp. What loads and what does not: docs/scene-format.md.
#include <string>
#include <vector>

#include "scene/mesh.h"
#include "scene/scene.h"

namespace iso {

struct GltfTextureRef {
  int texture = -1;  // index into GltfModel::textures; -1: none
};

// The glTF metallic-roughness material, factors and textures as in the file (an OBJ's MTL
// material is a Diffuse one in the same struct).
struct GltfMaterial {
  std::string name;
  MaterialType type = MaterialType::MetallicRoughness;
  Vec3f baseColor{1, 1, 1};
  float metallic = 1, roughness = 1;
  Vec3f emissive{0, 0, 0};  // emissiveFactor times KHR_materials_emissive_strength
  float normalScale = 1;
  GltfTextureRef baseColorTexture, metallicRoughnessTexture, normalTexture, emissiveTexture;
  bool doubleSided = false;
};

enum class TextureWrap { Repeat, Clamp, Mirror };

struct GltfTexture {
  int image = -1;  // index into GltfModel::images
  TextureWrap wrapS = TextureWrap::Repeat, wrapT = TextureWrap::Repeat;
  bool nearest = false;  // magFilter NEAREST
};

// Images stay encoded (PNG, JPEG) until a material that is used needs them.
struct GltfImage {
  std::string name;  // uri or "image N", for messages
  std::vector<unsigned char> encoded;
};

struct GltfInstance {
  int mesh = 0;
  Transform toFile;  // node's world transform within the file
  std::string node;  // "/nodes/N" (and the node's name, if any)
};

struct GltfCamera {
  std::string name;
  CameraDesc desc;  // in the file's space
};

struct GltfModel {
  std::string path;
  std::vector<std::vector<TriangleMesh>> meshes;  // [mesh][primitive], object space
  std::vector<std::string> meshNames;
  std::vector<GltfInstance> instances;
  std::vector<GltfMaterial> materials;
  std::vector<GltfTexture> textures;
  std::vector<GltfImage> images;
  std::vector<GltfCamera> cameras;
  std::vector<LightDesc> lights;  // KHR_lights_punctual, in the file's space
  std::vector<std::string> warnings;  // one per unsupported optional feature
};

// Throws InputError naming the file and the JSON path of what is wrong.
GltfModel loadGltf(const std::string& path);
// Wavefront OBJ with its MTL materials (scene/obj.cpp): one mesh, a primitive per material,
// Kd as a Lambertian colour, Ke as emission. Throws InputError naming the file and the face.
GltfModel loadObj(const std::string& path);

// One triangle mesh with one metallic-roughness material, in world space.
struct GltfMeshOut {
  std::string name;
  std::vector<Vec3f> positions, normals;  // normals unit, one per position
  std::vector<uint32_t> indices;          // three per triangle, counter-clockwise = front
  std::vector<Vec3f> colors;              // linear RGB per position (COLOR_0), or none
  Vec3f color{0.8f, 0.8f, 0.8f};
  float metallic = 0, roughness = 0.5f;
};

// Writes `mesh` as binary glTF (.glb) or as .gltf with its buffer embedded, through a
// temporary file: a failed write leaves nothing behind. Throws InputError.
void saveGltfMesh(const std::string& path, const GltfMeshOut& mesh);

}  // namespace iso
