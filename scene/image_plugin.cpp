#include "scene/image_plugin.h"

#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <stdexcept>

namespace iso {
namespace {

constexpr const char* kLibrary = "libisotrace_oiio.so";

// The folders to look in: the program's (isotrace), the shared object's holding this code (the
// Python module), and the build folder the library was built in; only $ISOTRACE_PLUGIN_DIR if set.
std::vector<std::filesystem::path> pluginFolders() {
  std::vector<std::filesystem::path> folders;
  if (const char* dir = std::getenv("ISOTRACE_PLUGIN_DIR")) return {dir};
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) folders.push_back(exe.parent_path());
  Dl_info info;
  if (dladdr(reinterpret_cast<void*>(&imagePlugin), &info) && info.dli_fname && *info.dli_fname)
    folders.push_back(std::filesystem::path(info.dli_fname).parent_path());
#ifdef ISOTRACE_BUILD_DIR
  folders.push_back(ISOTRACE_BUILD_DIR);
#endif
  return folders;
}

ImagePlugin* load() {
  std::string errors;
  for (const std::filesystem::path& folder : pluginFolders()) {
    const std::filesystem::path path = folder / kLibrary;
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) continue;
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle) {
      errors += std::string("; ") + dlerror();
      continue;
    }
    auto entry = reinterpret_cast<ImagePlugin* (*)()>(dlsym(handle, "isotraceImagePlugin"));
    if (entry) return entry();  // (never closed: its objects live as long as the process)
    errors += "; " + path.string() + ": no isotraceImagePlugin";
  }
  throw PluginMissing(
      std::string("cannot load ") + kLibrary + ", isotrace's OpenImageIO reader and writer" +
      (errors.empty()
           ? " (not found beside the program, in its build folder or in $ISOTRACE_PLUGIN_DIR)"
           : errors));
}

}  // namespace

ImagePlugin& imagePlugin() {
  static ImagePlugin* const plugin = load();
  return *plugin;
}

}  // namespace iso
