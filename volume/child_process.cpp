// Reading a volume in a child process (child_process.h). Debian builds GDCM with
// its assertions on, and malformed files trip them (pydicom's own test files do); OpenVDB trusts
// the sizes in its streams and allocates whatever they say, or reads past its buffers; libnifti
// overflows a stack buffer on a malformed header (a fuzzer finding). An
// abort(), a crash or an out-of-memory there would take isotrace down with it, so such a
// library reads in a child: the child hands back the samples through a memfd (the parent maps
// them: no copy) and the rest (geometry, notes, or the InputError) through a pipe; if it dies,
// the parent reports the file as malformed, in one line. The child enters no TBB (OpenVDB's
// serial calls, BrickGrid's serial build): fork() does not copy TBB's worker threads.
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstring>
#include <sstream>

#include "volume/input_error.h"
#include "volume/loaders.h"

namespace iso {
namespace {

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif
#else
constexpr bool kAddressSanitizer = false;
#endif

// The fixed part of a volume's report: kind, dims, the window held, origin, spacing, the 3x4
// placement, array sizes.
struct Header {
  char tag[2];  // "ok"
  int32_t sparse;
  int32_t type;  // ScalarType of a dense grid
  int32_t dims[3];
  int32_t first[3], extent[3];  // the samples held (a window's; else 0 and dims)
  int32_t bricks[3];
  double origin[3], spacing[3], toWorld[12];
  uint64_t blockCount, uniformCount;
};

bool writeAll(int fd, const void* data, size_t size, off_t* at = nullptr) {
  const char* p = static_cast<const char*>(data);
  for (size_t done = 0; done < size;) {
    const ssize_t n = at ? pwrite(fd, p + done, size - done, *at + off_t(done)) : write(fd, p + done, size - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    done += size_t(n);
  }
  if (at) *at += off_t(size);
  return true;
}

bool g_inReaderChild = false;

[[noreturn]] void childMain(int bytesFd, int reportFd, const std::string& path,
                            const std::function<std::string(int)>& work) {
  g_inReaderChild = true;  // no TBB from here on (child_process.h, inReaderChild)
  // The parent's handlers (SIGINT's, a fuzzer's) are not the child's business; a crash here
  // ends the child, which the parent reports. The library's own messages are muted.
  for (int sig : {SIGABRT, SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGINT, SIGTERM}) std::signal(sig, SIG_DFL);
  const int devNull = open("/dev/null", O_WRONLY);
  if (devNull >= 0) dup2(devNull, 2);
  // No more address space than the machine has memory: a file that asks for more fails here
  // (bad_alloc) instead of swapping the machine to a halt. Not under AddressSanitizer, whose
  // shadow memory reserves terabytes of address space.
  const long pages = sysconf(_SC_PHYS_PAGES), pageSize = sysconf(_SC_PAGE_SIZE);
  if (pages > 0 && pageSize > 0 && !kAddressSanitizer) {
    const rlim_t limit = rlim_t(pages) * rlim_t(pageSize);
    const rlimit r{limit, limit};
    setrlimit(RLIMIT_AS, &r);
  }
  std::string report;
  try {
    report = "ok" + work(bytesFd);
  } catch (const InputError& e) {
    report = std::string("er") + e.what();
  } catch (const std::bad_alloc&) {
    report = "er" + path + ": it asks for more memory than the machine has (a malformed file?)";
  } catch (const std::exception& e) {
    report = "er" + path + ": cannot read: " + e.what();
  }
  _exit(writeAll(reportFd, report.data(), report.size()) ? 0 : 3);
}

// A volume's samples into `fd`, the rest as the report (after "ok").
std::string sendVolume(const VolumeFile& v, int fd) {
  Header h{};
  h.tag[0] = 'o', h.tag[1] = 'k';
  const Grid& g = v.grid;
  for (int a = 0; a < 3; ++a) {
    h.dims[a] = g.dims()[a];
    h.first[a] = g.windowFirst()[a];
    h.extent[a] = g.windowExtent()[a];
    h.origin[a] = g.origin()[a];
    h.spacing[a] = g.spacing()[a];
  }
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) h.toWorld[r * 4 + c] = v.toWorld.m[r][c];
  off_t at = 0;
  bool ok = true;
  if (const SparseSamples* s = g.sparse()) {
    h.sparse = 1;
    for (int a = 0; a < 3; ++a) h.bricks[a] = s->bricks[a];
    h.blockCount = s->blockCount;
    h.uniformCount = s->uniformCount;
    ok = writeAll(fd, s->slot, s->brickCount() * 4, &at) &&
         writeAll(fd, s->blocks, s->blockCount * SparseSamples::kBlockSize * 4, &at) &&
         writeAll(fd, s->uniform, s->uniformCount * 4, &at);
  } else {
    h.type = int32_t(g.type());
    ok = writeAll(fd, g.data(), g.bytes(), &at);
  }
  if (!ok) _exit(3);
  std::string report(reinterpret_cast<const char*>(&h) + 2, sizeof h - 2);
  report += v.format + '\n';
  for (const std::string& note : v.notes) report += note + '\n';
  return report;
}

}  // namespace

bool inReaderChild() { return g_inReaderChild; }

ChildOutput runInChildProcess(const std::string& path, const char* library, const std::function<std::string(int)>& work) {
  const std::string malformed = std::string(library) +
                                " stopped reading it (an assertion, a crash or no memory inside the library): a malformed file";
  const int bytesFd = memfd_create("isotrace-volume", MFD_CLOEXEC);
  int pipeFds[2];
  if (bytesFd < 0 || pipe2(pipeFds, O_CLOEXEC) != 0) throw InputError(path, "", "cannot start a reader process");
  struct Closer {
    int fd;
    ~Closer() { close(fd); }
  } closer{bytesFd};
  const pid_t pid = fork();
  if (pid < 0) throw InputError(path, "", "cannot start a reader process");
  if (pid == 0) {
    close(pipeFds[0]);
    childMain(bytesFd, pipeFds[1], path, work);
  }
  close(pipeFds[1]);
  std::string report;
  char buffer[4096];
  for (ssize_t n; (n = ::read(pipeFds[0], buffer, sizeof buffer)) != 0;) {
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) break;
    report.append(buffer, size_t(n));
  }
  close(pipeFds[0]);
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  const bool exited = WIFEXITED(status) && WEXITSTATUS(status) == 0;
  if (exited && report.compare(0, 2, "er") == 0) throw InputError(report.substr(2));
  if (!exited || report.compare(0, 2, "ok") != 0) throw InputError(path, "", malformed);
  ChildOutput out;
  out.report = report.substr(2);
  struct stat info;
  if (fstat(bytesFd, &info) != 0) throw InputError(path, "", malformed);
  out.size = size_t(info.st_size);
  if (out.size > 0) {
    void* map = mmap(nullptr, out.size, PROT_READ, MAP_SHARED, bytesFd, 0);
    if (map == MAP_FAILED) throw InputError(path, "", "cannot map the samples its reader made");
    const size_t size = out.size;
    out.bytes = std::shared_ptr<const void>(map, [size](const void* p) { munmap(const_cast<void*>(p), size); });
  }
  return out;
}

VolumeFile readInChildProcess(const std::string& path, const char* library, const std::function<VolumeFile()>& read) {
  const ChildOutput child = runInChildProcess(path, library, [&](int fd) { return sendVolume(read(), fd); });
  const std::string malformed = std::string(library) + " gave back a malformed volume";
  Header h;
  if (child.report.size() < sizeof h - 2) throw InputError(path, "", malformed);
  h.tag[0] = 'o', h.tag[1] = 'k';
  std::memcpy(reinterpret_cast<char*>(&h) + 2, child.report.data(), sizeof h - 2);
  const Vec3i dims{h.dims[0], h.dims[1], h.dims[2]}, first{h.first[0], h.first[1], h.first[2]},
      extent{h.extent[0], h.extent[1], h.extent[2]};
  const size_t brickCount = size_t(h.bricks[0]) * size_t(h.bricks[1]) * size_t(h.bricks[2]);
  const ScalarType type = ScalarType(h.type);
  const size_t bytes = h.sparse ? (brickCount + h.blockCount * SparseSamples::kBlockSize + h.uniformCount) * 4
                                : size_t(extent.x) * size_t(extent.y) * size_t(extent.z) * scalarTypeSize(type);
  if (child.size != bytes || bytes == 0) throw InputError(path, "", malformed);
  VolumeFile v;
  const Vec3d origin{h.origin[0], h.origin[1], h.origin[2]}, spacing{h.spacing[0], h.spacing[1], h.spacing[2]};
  if (h.sparse) {
    auto s = std::make_shared<SparseSamples>();
    s->bricks = {h.bricks[0], h.bricks[1], h.bricks[2]};
    s->slot = static_cast<const int32_t*>(child.bytes.get());
    s->blocks = reinterpret_cast<const float*>(s->slot + brickCount);
    s->uniform = s->blocks + h.blockCount * SparseSamples::kBlockSize;
    s->blockCount = h.blockCount;
    s->uniformCount = h.uniformCount;
    s->owner = child.bytes;
    v.grid = extent == dims ? Grid(dims, std::move(s), origin, spacing) : Grid(dims, std::move(s), first, extent, origin, spacing);
  } else if (extent == dims) {
    v.grid = Grid(dims, type, child.bytes, origin, spacing);
  } else {
    v.grid = Grid(dims, type, child.bytes, first, extent, origin, spacing);
  }
  v.toWorld = Transform::fromRows(h.toWorld);
  std::istringstream lines(child.report.substr(sizeof h - 2));
  std::getline(lines, v.format);
  for (std::string line; std::getline(lines, line);) v.notes.push_back(line);
  return v;
}

BrickGrid rangesInChildProcess(const std::string& path, const char* library, const std::function<BrickGrid()>& ranges) {
  const ChildOutput child = runInChildProcess(path, library, [&](int fd) {
    const BrickGrid b = ranges();
    std::vector<float> lohi(2 * b.size());
    for (uint32_t i = 0; i < b.size(); ++i) lohi[i] = b.brickMin(i), lohi[b.size() + i] = b.brickMax(i);
    off_t at = 0;
    if (!writeAll(fd, lohi.data(), lohi.size() * sizeof(float), &at)) _exit(3);
    const Vec3i d = b.dims();
    return std::string(reinterpret_cast<const char*>(&d), sizeof d);
  });
  const std::string malformed = std::string(library) + "'s reader gave back malformed brick ranges";
  Vec3i dims;
  if (child.report.size() != sizeof dims || !child.bytes) throw InputError(path, "", malformed);
  std::memcpy(&dims, child.report.data(), sizeof dims);
  const size_t count = child.size / (2 * sizeof(float));
  try {
    const float* lohi = static_cast<const float*>(child.bytes.get());
    return BrickGrid::fromRanges(dims, lohi, lohi + count, count);
  } catch (const std::invalid_argument&) {
    throw InputError(path, "", malformed);
  }
}

}  // namespace iso
