#include "renderer/video.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "volume/input_error.h"

namespace iso {
namespace {
namespace fs = std::filesystem;

std::string extensionOf(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  return ext;
}

// The last line ffmpeg wrote (its error), at most 300 characters.
std::string lastLine(const std::string& file) {
  std::ifstream in(file);
  std::string line, last;
  while (std::getline(in, line))
    if (line.find_first_not_of(" \t\r") != std::string::npos) last = line;
  return last.substr(0, 300);
}
}  // namespace

bool isVideoName(const std::string& path) {
  const std::string ext = extensionOf(path);
  return ext == ".mp4" || ext == ".webm";
}

std::string findFfmpeg(const std::string& what) {
  if (const char* env = std::getenv("ISOTRACE_FFMPEG"); env && *env) {
    if (access(env, X_OK) != 0)
      throw InputError("ISOTRACE_FFMPEG", "", std::string("'") + env + "' is not an executable program");
    return env;
  }
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path ? path : "/usr/bin:/bin");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const std::string candidate = (dir.empty() ? "." : dir) + "/ffmpeg";
    if (access(candidate.c_str(), X_OK) == 0) return candidate;
  }
  throw InputError(what, "", "writing a video needs the ffmpeg program (Debian package ffmpeg; scripts/setup.sh "
                             "installs it), or write numbered images (-o out.png)");
}

VideoWriter::VideoWriter(const std::string& path, int width, int height, double fps)
    : m_path(path), m_width(width), m_height(height) {
  const std::string ffmpeg = findFfmpeg(path);
  const fs::path target(path);
  if (target.has_parent_path() && !fs::is_directory(target.parent_path()))
    throw InputError(path, "", "output directory does not exist");
  const std::string ext = extensionOf(path);
  m_temp = (target.parent_path() / ("." + target.stem().string() + ".partial-" + std::to_string(getpid()) + ext)).string();
  m_errFile = m_temp + ".log";
  char size[32], rate[32];
  std::snprintf(size, sizeof size, "%dx%d", width, height);
  std::snprintf(rate, sizeof rate, "%g", fps);
  // H.264 and VP9 in 4:2:0 need even sides: padded by a black row or column where odd.
  std::vector<std::string> args = {ffmpeg, "-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo",
                                   "-pix_fmt", "rgb24", "-s", size, "-r", rate, "-i", "-",
                                   "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p"};
  if (ext == ".mp4")
    args.insert(args.end(), {"-c:v", "libx264", "-crf", "18", "-preset", "medium", "-movflags", "+faststart", "-f", "mp4"});
  else
    args.insert(args.end(), {"-c:v", "libvpx-vp9", "-crf", "30", "-b:v", "0", "-row-mt", "1", "-f", "webm"});
  args.push_back(m_temp);

  int pipeFds[2];
  if (pipe2(pipeFds, O_CLOEXEC) != 0) throw InputError(path, "", "cannot start ffmpeg: no pipe");
  const int errFd = open(m_errFile.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (errFd < 0) {
    close(pipeFds[0]), close(pipeFds[1]);
    throw InputError(path, "", "cannot write in the output's folder");
  }
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  m_pid = fork();
  if (m_pid == 0) {
    dup2(pipeFds[0], 0);
    dup2(errFd, 1);
    dup2(errFd, 2);
    signal(SIGINT, SIG_IGN);  // a Ctrl-C stops the render, which then ends the video itself
    signal(SIGPIPE, SIG_DFL);
    execv(argv[0], argv.data());
    _exit(127);
  }
  close(pipeFds[0]);
  close(errFd);
  if (m_pid < 0) {
    close(pipeFds[1]);
    throw InputError(path, "", "cannot start ffmpeg");
  }
  m_in = pipeFds[1];
}

void VideoWriter::add(const std::vector<uint8_t>& rgb) {
  const char* p = reinterpret_cast<const char*>(rgb.data());
  size_t left = std::min(rgb.size(), size_t(m_width) * m_height * 3);
  // (SIGPIPE is ignored for the write: a dead ffmpeg is an EPIPE here, reported with its words.)
  struct sigaction ignore {}, previous {};
  ignore.sa_handler = SIG_IGN;
  sigaction(SIGPIPE, &ignore, &previous);
  while (left > 0) {
    const ssize_t n = write(m_in, p, left);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      sigaction(SIGPIPE, &previous, nullptr);
      stop();
      const std::string why = lastLine(m_errFile);
      std::error_code ec;
      fs::remove(m_errFile, ec);
      throw InputError(m_path, "", "ffmpeg stopped taking frames" + (why.empty() ? std::string() : ": " + why));
    }
    p += n;
    left -= size_t(n);
  }
  sigaction(SIGPIPE, &previous, nullptr);
  ++m_frames;
}

void VideoWriter::finish() {
  close(m_in);
  m_in = -1;
  int status = 0;
  while (waitpid(m_pid, &status, 0) < 0 && errno == EINTR) {
  }
  m_pid = -1;
  std::error_code ec;
  const std::string why = lastLine(m_errFile);
  fs::remove(m_errFile, ec);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    fs::remove(m_temp, ec);
    throw InputError(m_path, "", "ffmpeg could not write the video" + (why.empty() ? std::string() : ": " + why));
  }
  fs::rename(m_temp, m_path, ec);
  if (ec) {
    fs::remove(m_temp, ec);
    throw InputError(m_path, "", "cannot write the video: " + ec.message());
  }
  m_finished = true;
}

void VideoWriter::stop() {
  if (m_in >= 0) close(m_in);
  m_in = -1;
  if (m_pid > 0) {
    kill(m_pid, SIGKILL);
    while (waitpid(m_pid, nullptr, 0) < 0 && errno == EINTR) {
    }
  }
  m_pid = -1;
  std::error_code ec;
  fs::remove(m_temp, ec);
}

VideoWriter::~VideoWriter() {
  if (m_finished) return;
  stop();
  std::error_code ec;
  fs::remove(m_errFile, ec);
}

}  // namespace iso
