#include "tests/test_util.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <csignal>

#include <filesystem>
#include <fstream>
#include <sstream>

namespace iso::test {

namespace fs = std::filesystem;

std::string scratchDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::path(ISOTRACE_SCRATCH_DIR) / (std::string(info->test_suite_name()) + "." + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

void writeText(const std::string& path, const std::string& text) { writeBytes(path, text); }

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

static std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

Process::Process(const std::string& command) {
  int fds[2];
  if (pipe2(fds, O_CLOEXEC) != 0) throw std::runtime_error("pipe failed");
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  // stdin empty, stdout to /dev/null unless the command sends it elsewhere: a child left running
  // (an MPI rank) must not hold ctest's output pipe open, or ctest waits for it.
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, fds[1], 2);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sigset_t defaults, none;
  sigemptyset(&defaults);
  sigaddset(&defaults, SIGINT);
  sigaddset(&defaults, SIGTERM);
  sigaddset(&defaults, SIGPIPE);
  sigemptyset(&none);
  posix_spawnattr_setsigdefault(&attr, &defaults);
  posix_spawnattr_setsigmask(&attr, &none);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGDEF | POSIX_SPAWN_SETSIGMASK);
  const std::string line = "exec " + command;
  char* argv[] = {const_cast<char*>("sh"), const_cast<char*>("-c"), const_cast<char*>(line.c_str()), nullptr};
  const int rc = posix_spawn(&m_pid, "/bin/sh", &actions, &attr, argv, environ);
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attr);
  close(fds[1]);
  m_errFd = fds[0];
  if (rc != 0) throw std::runtime_error("posix_spawn failed");
}

Process::~Process() {
  if (m_pid > 0) {
    kill(m_pid, SIGKILL);
    waitpid(m_pid, nullptr, 0);
  }
  if (m_errFd >= 0) close(m_errFd);
}

bool Process::readSome(double seconds) {
  if (m_errFd < 0) return false;
  pollfd p{m_errFd, POLLIN, 0};
  if (poll(&p, 1, int(seconds * 1000)) <= 0) return false;
  char buffer[4096];
  const ssize_t n = read(m_errFd, buffer, sizeof buffer);
  if (n <= 0) {
    close(m_errFd);
    m_errFd = -1;
    return false;
  }
  m_err.append(buffer, size_t(n));
  return true;
}

bool Process::waitForErr(const std::string& text, double safetySeconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(safetySeconds);
  while (m_err.find(text) == std::string::npos) {
    const double left = std::chrono::duration<double>(end - std::chrono::steady_clock::now()).count();
    if (left <= 0 || !readSome(left)) return m_err.find(text) != std::string::npos;
  }
  return true;
}

int Process::openPipeForWriting(const std::string& path, double safetySeconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(safetySeconds);
  while (std::chrono::steady_clock::now() < end) {
    // Without a reader a non-blocking open fails with ENXIO; a blocking one would wait for ever
    // if the process died before opening the pipe.
    const int fd = open(path.c_str(), O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd >= 0) {
      fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) & ~O_NONBLOCK);
      return fd;
    }
    siginfo_t ended{};
    if (errno != ENXIO || m_pid <= 0 || waitid(P_PID, id_t(m_pid), &ended, WEXITED | WNOHANG | WNOWAIT) != 0 || ended.si_pid != 0)
      return -1;  // (the process, if it ended, is left for wait() to reap)
    readSome(0.01);  // takes what the process says meanwhile; at most 10 ms between looks
  }
  return -1;
}

void Process::signal(int sig) {
  if (m_pid > 0) kill(m_pid, sig);
}

int Process::wait(double safetySeconds) {
  if (m_pid <= 0) return m_status;
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(safetySeconds);
  while (m_errFd >= 0) {
    const double left = std::chrono::duration<double>(end - std::chrono::steady_clock::now()).count();
    if (left <= 0) break;
    readSome(left);
  }
  if (m_errFd >= 0) {  // still running after the safety net
    kill(m_pid, SIGKILL);
    waitpid(m_pid, nullptr, 0);
    m_pid = -1;
    return m_status = -1;
  }
  int raw = 0;
  waitpid(m_pid, &raw, 0);
  m_pid = -1;
  m_status = WIFEXITED(raw) ? WEXITSTATUS(raw) : WIFSIGNALED(raw) ? 128 + WTERMSIG(raw) : -1;
  return m_status;
}

std::vector<pid_t> processesWithArgument(const std::string& program, const std::string& argument) {
  std::vector<pid_t> found;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator("/proc", ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream in(entry.path() / "cmdline", std::ios::binary);
    std::string first;
    std::getline(in, first, '\0');
    if (first != program) continue;
    for (std::string word; std::getline(in, word, '\0');)
      if (word == argument) {
        found.push_back(pid_t(std::stol(name)));
        break;
      }
  }
  return found;
}

CommandResult runIsotrace(const std::string& args) { return runCommand(std::string(ISOTRACE_BINARY) + " " + args); }

CommandResult runCommand(const std::string& command) {
  // ctest runs tests in parallel processes: capture files are named after the test.
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::path(ISOTRACE_SCRATCH_DIR) / "commands";
  fs::create_directories(dir);
  const std::string stem = (dir / (std::string(info->test_suite_name()) + "." + info->name())).string();
  const std::string out = stem + ".out", err = stem + ".err";
  // A safety net against a hang, not a timing assumption: a command still running after 10
  // minutes is stopped (status 124, said in err) so that the test fails by name instead of
  // holding the whole suite; stdin is empty, as under CI.
  std::string quoted;
  for (char c : command) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  const std::string cmd = "timeout -k 10 600 /bin/sh -c '" + quoted + "' </dev/null >" + out + " 2>" + err;
  const int raw = std::system(cmd.c_str());
  CommandResult r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  if (r.status == 124) r.err += "(test_util: stopped after 600 s: " + command + ")\n";
  return r;
}

std::string mixedScene() {
  return R"({"camera": {"position": [0, 1.5, 4], "look_at": [0, 0.5, 0]}, "film": {"width": 32, "height": 24},
    "meshes": [{"shape": "quad", "transform": {"scale": 3}, "material": "floor"}],
    "volumes": [{"procedural": {"field": "sphere", "resolution": [24, 24, 24]}, "transform": {"translate": [0, 1, 0]},
                 "isosurfaces": [{"value": 0.6, "inside": "below", "material": "ball"}]}],
    "materials": {"floor": {"type": "diffuse", "color": 0.7}, "ball": {"type": "metallic_roughness", "color": [0.8, 0.3, 0.2]}},
    "lights": [{"type": "point", "position": [2, 4, 2], "intensity": 30}, {"type": "environment", "radiance": 0.3}]})";
}

std::vector<float> readExr(const std::string& path, std::vector<std::string>* channels,
                           std::map<std::string, std::string>* metadata) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) return {};
  const OIIO::ImageSpec& spec = in->spec();
  std::vector<float> data(size_t(spec.width) * spec.height * spec.nchannels);
  in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, data.data());
  if (channels) *channels = spec.channelnames;
  if (metadata)
    for (const char* key : {"isotrace:spp", "isotrace:interrupted", "isotrace:integrator", "isotrace:spp_mean",
                            "isotrace:spp_max", "isotrace:clamp", "isotrace:overrides"})
      if (spec.find_attribute(key)) (*metadata)[key] = spec.get_string_attribute(key);
  return data;
}

}  // namespace iso::test
