#pragma once
// Reading with a library that may abort, crash or allocate without bound on a malformed file
// (GDCM, OpenVDB, libnifti): the work runs in a forked child process (volume/child_process.cpp),
// and the parent gets back its result, or one InputError naming the library and the file.
// Declared apart from the loaders so that code the child runs (BrickGrid's build) can ask
// inReaderChild() without including them.
#include <functional>
#include <memory>
#include <string>

namespace iso {

struct VolumeFile;
class BrickGrid;

// Runs `read` in a child process and returns its volume: the samples (of a window too) come back
// through shared memory the parent maps; the child's InputError comes back as is, its death as an
// InputError naming `library` and the file.
VolumeFile readInChildProcess(const std::string& path, const char* library, const std::function<VolumeFile()>& read);
// The same for anything else such a library reads (a header alone, a volume's brick ranges):
// `work(fd)` runs in the child, returns a report and may write bytes to `fd`; the parent gets the
// report and those bytes, mapped (null when none). Errors as above.
struct ChildOutput {
  std::string report;
  std::shared_ptr<const void> bytes;
  size_t size = 0;
};
ChildOutput runInChildProcess(const std::string& path, const char* library, const std::function<std::string(int fd)>& work);
// A volume's brick ranges computed in a child process (`ranges` runs there), for such a library.
BrickGrid rangesInChildProcess(const std::string& path, const char* library, const std::function<BrickGrid()>& ranges);
// True in such a child. fork() copies TBB's scheduler state but not its worker threads, so a
// parallel loop there can wait for ever for a worker that is not there (a load hung so in CI):
// the child runs no TBB, and code it calls (BrickGrid's build) loops serially when this is true.
bool inReaderChild();

}  // namespace iso
