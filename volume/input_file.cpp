#include "volume/input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "volume/input_error.h"

namespace iso {

InputFile checkInputFile(const std::string& path, const std::string& what, bool streamAllowed) {
  struct stat st {};
  if (stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT || errno == ENOTDIR) throw InputError(path, "", what + " not found");
    throw InputError(path, "", "cannot open " + what + ": " + std::strerror(errno));
  }
  InputFile f;
  if (S_ISREG(st.st_mode)) {
    f.size = uint64_t(st.st_size);
    return f;
  }
  if (S_ISDIR(st.st_mode)) throw InputError(path, "", "is a directory, not a " + what);
  if (S_ISCHR(st.st_mode)) throw InputError(path, "", "is a character device, not a " + what);
  if (S_ISBLK(st.st_mode)) throw InputError(path, "", "is a block device, not a " + what);
  if (S_ISFIFO(st.st_mode)) {
    if (!streamAllowed)
      throw InputError(path, "", "is a named pipe; a " + what + " must be a regular file (it is read more than once)");
    f.stream = true;
    return f;
  }
  throw InputError(path, "", "is not a regular file (a socket or another special file), not a " + what);
}

namespace {

template <typename Container>
Container readAll(const std::string& path, const std::string& what, uint64_t streamCap) {
  const InputFile f = checkInputFile(path, what);
  const int fd = open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError(path, "", "cannot open " + what + ": " + std::strerror(errno));
  struct Closer {
    int fd;
    ~Closer() { close(fd); }
  } closer{fd};
  // A regular file that grows while it is read is read to the size it had.
  const uint64_t limit = f.stream ? streamCap + 1 : f.size;
  Container data;
  data.reserve(f.stream ? 0 : size_t(f.size));
  char buffer[1 << 16];
  while (data.size() < limit) {
    const ssize_t n = read(fd, buffer, size_t(std::min<uint64_t>(sizeof buffer, limit - data.size())));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw InputError(path, "byte " + std::to_string(data.size()), "read error: " + std::string(std::strerror(errno)));
    if (n == 0) break;
    data.insert(data.end(), buffer, buffer + n);
  }
  if (f.stream && data.size() > streamCap)
    throw InputError(path, "", "a " + what + " read from a named pipe may hold at most " + std::to_string(streamCap) +
                                   " bytes; this one holds more");
  return data;
}

}  // namespace

std::string readWholeFile(const std::string& path, const std::string& what, uint64_t streamCap) {
  return readAll<std::string>(path, what, streamCap);
}

std::vector<uint8_t> readWholeBytes(const std::string& path, const std::string& what, uint64_t streamCap) {
  return readAll<std::vector<uint8_t>>(path, what, streamCap);
}

}  // namespace iso
