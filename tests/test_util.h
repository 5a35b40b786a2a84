#pragma once
// Helpers shared by the tests: data paths, a seeded RNG, running the isotrace binary, bad input.
#include <gtest/gtest.h>

#include <sys/types.h>

#include <cstdio>
#include <map>
#include <random>
#include <string>
#include <vector>

namespace iso::test {

inline std::string dataPath(const std::string& rel) { return std::string(ISOTRACE_DATA_DIR) + "/" + rel; }

struct CommandResult {
  int status = -1;
  std::string err;  // stderr
  std::string out;  // stdout
};

// Runs `isotrace <args>` through the shell, capturing stdout and stderr.
CommandResult runIsotrace(const std::string& args);
// Runs a shell command line, capturing stdout and stderr (stdin empty; stopped after 10 minutes,
// status 124, a safety net against a hang).
CommandResult runCommand(const std::string& command);

// A process the test talks to while it runs: a shell command line, started with SIGINT and
// SIGTERM at their default actions and none blocked (as from a terminal, not as a job that a
// non-interactive shell starts with `&`, which begins with SIGINT ignored). Its stderr comes to
// the test through a pipe, so the test can wait for what the process says (an event, never a
// time); stdin is empty and stdout goes to /dev/null unless the command line sends it elsewhere.
// The destructor kills and reaps a process still running.
class Process {
 public:
  explicit Process(const std::string& command);
  ~Process();
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  // Reads stderr until it holds `text`: true then; false if stderr closed first (the process
  // ended) or after `safetySeconds` (a safety net against a hang, not a timing assumption).
  bool waitForErr(const std::string& text, double safetySeconds = 300);
  void signal(int sig);
  // Waits for the end (reading the rest of stderr): the exit status, or 128 + the signal that
  // ended it. A process still running after `safetySeconds` is killed and -1 returned.
  int wait(double safetySeconds = 300);
  const std::string& err() const { return m_err; }
  pid_t pid() const { return m_pid; }
  // Opens the named pipe `path` for writing once a reader has opened it (the event: the process
  // is reading it); -1 if this process ended first, or after `safetySeconds`.
  int openPipeForWriting(const std::string& path, double safetySeconds = 300);

 private:
  bool readSome(double seconds);  // false at end of stderr or after `seconds`
  pid_t m_pid = -1;
  int m_errFd = -1;
  int m_status = -1;
  std::string m_err;
};

// The processes running `program` (their first word) with `argument` as one of the others.
std::vector<pid_t> processesWithArgument(const std::string& program, const std::string& argument);

// A small mixed scene: a floor quad, an iso-surface ball, a point light and a sky (32x24).
std::string mixedScene();
// An image's pixels as float (empty if it cannot be read), its channel names and isotrace's
// metadata (isotrace:spp, :interrupted, :integrator, :spp_mean, :spp_max, :clamp, :overrides).
std::vector<float> readExr(const std::string& path, std::vector<std::string>* channels = nullptr,
                           std::map<std::string, std::string>* metadata = nullptr);

// A scratch directory unique to the current test, emptied first: under the build tree
// (build/test_scratch/SUITE.NAME), so that two clones' suites can run at once.
std::string scratchDir();
void writeText(const std::string& path, const std::string& text);
void writeBytes(const std::string& path, const std::string& bytes);

// Bad input: `load()` must throw an InputError (or another exception type E) whose message
// names `name` (a file, a place) and holds `fragment`, in one line.
template <typename E, typename F>
void expectRefusal(F&& load, const std::string& name, const std::string& fragment) {
  try {
    load();
    ADD_FAILURE() << "no error for " << name;
  } catch (const E& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(name), std::string::npos) << msg;
    EXPECT_NE(msg.find(fragment), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line: " << msg;
  }
}

}  // namespace iso::test
