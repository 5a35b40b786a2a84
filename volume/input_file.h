#pragma once
// What a path the user names is, checked before anything is read from it. A regular file is
// read at its size. A FIFO (a named pipe, e.g. a stream from another program) is read as a
// stream, never further than the format's own sizes allow or a stated cap. Everything else
// is refused by name at once: a missing path, a directory, a character or block device
// (/dev/zero, /dev/sda) and a socket. Errors are InputErrors naming the path.
#include <cstdint>
#include <string>
#include <vector>

namespace iso {

struct InputFile {
  bool stream = false;  // a FIFO: its length is known only once it is read
  uint64_t size = 0;    // bytes, for a regular file
};

// `what` names the expected content in errors ("scene file", "glTF file"). With
// `streamAllowed` false a FIFO is refused too: for readers that open a path more than once or
// seek in it (NIfTI, DICOM, OpenVDB, images).
InputFile checkInputFile(const std::string& path, const std::string& what, bool streamAllowed = true);

// The whole content: a regular file at its size, a stream up to `streamCap` bytes (one more
// byte makes it an error that states the cap). The path is checked as above.
std::string readWholeFile(const std::string& path, const std::string& what, uint64_t streamCap);
// The same as bytes (a volume's samples are read once, with no copy from a string).
std::vector<uint8_t> readWholeBytes(const std::string& path, const std::string& what, uint64_t streamCap);

// Caps for streams of text formats (a regular file is read at whatever size it has).
constexpr uint64_t kSceneStreamCap = uint64_t(64) << 20;    // a scene's JSON
constexpr uint64_t kMeshStreamCap = uint64_t(1) << 30;      // a glTF's JSON, its buffers and images
constexpr uint64_t kVolumeStreamCap = uint64_t(4) << 30;    // a volume file read whole (NRRD, MHD, VTK)

}  // namespace iso
