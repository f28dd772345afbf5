#include "telehand/app/process.h"

#include <fcntl.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <thread>

extern char** environ;

namespace telehand::app {

namespace {
std::runtime_error sysError(const std::string& what, int err) {
  return std::runtime_error(what + ": " + std::strerror(err));
}
}  // namespace

std::optional<std::string> findProgram(const std::string& name) {
  if (name.find('/') != std::string::npos) {
    return access(name.c_str(), X_OK) == 0 ? std::optional(name) : std::nullopt;
  }
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    const std::string full = (dir.empty() ? "." : dir) + "/" + name;
    if (access(full.c_str(), X_OK) == 0) return full;
  }
  return std::nullopt;
}

Process::Process(const ProcessOptions& o) {
  if (o.argv.empty()) throw std::runtime_error("cannot run an empty command");
  std::string program = o.argv[0];
  if (o.search_path) {
    const auto found = findProgram(program);
    if (!found) throw sysError("cannot run " + program, ENOENT);
    program = *found;
  }
  std::vector<char*> args, envp;
  for (const auto& a : o.argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  if (o.env) {
    for (const auto& e : *o.env) envp.push_back(const_cast<char*>(e.c_str()));
    envp.push_back(nullptr);
  }
  char** const child_env = o.env ? envp.data() : environ;

  int in_fd = -1, out_fd = o.out_fd;
  bool own_out = false;
  if (o.null_stdin && (in_fd = open("/dev/null", O_RDONLY | O_CLOEXEC)) < 0) {
    throw sysError("cannot open /dev/null", errno);
  }
  if (out_fd < 0 && !o.out_path.empty()) {
    out_fd = open(o.out_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (out_fd < 0) {
      const int e = errno;
      if (in_fd >= 0) close(in_fd);
      throw sysError("cannot open " + o.out_path, e);
    }
    own_out = true;
  }
  const auto closeFds = [&] {
    if (in_fd >= 0) close(in_fd);
    if (own_out) close(out_fd);
  };
  int exec_err[2];
  if (pipe2(exec_err, O_CLOEXEC) != 0) {
    const int e = errno;
    closeFds();
    throw sysError("cannot start " + o.argv[0], e);
  }
  const pid_t parent = getpid();
  pid_ = fork();
  if (pid_ == 0) {
    if (o.die_with_parent) {
      prctl(PR_SET_PDEATHSIG, SIGTERM);
      if (getppid() != parent) _exit(127);
    }
    // Best effort: a child that keeps the parent's priority still runs.
    if (o.nice > 0) {
      [[maybe_unused]] const int niceness = ::nice(o.nice);
    }
    if (in_fd >= 0) dup2(in_fd, STDIN_FILENO);
    if (out_fd >= 0) {
      dup2(out_fd, STDOUT_FILENO);
      dup2(out_fd, STDERR_FILENO);
    }
    execve(program.c_str(), args.data(), child_env);
    const int e = errno;
    [[maybe_unused]] const ssize_t w = write(exec_err[1], &e, sizeof e);
    _exit(127);
  }
  const int fork_errno = errno;
  closeFds();
  close(exec_err[1]);
  if (pid_ < 0) {
    close(exec_err[0]);
    throw sysError("cannot fork " + o.argv[0], fork_errno);
  }
  int e = 0;
  ssize_t n;
  do n = read(exec_err[0], &e, sizeof e);
  while (n < 0 && errno == EINTR);
  close(exec_err[0]);
  if (n > 0) {  // exec failed; the child has exited already
    waitpid(pid_, &status_, 0);
    throw sysError("cannot run " + o.argv[0], e);
  }
  running_ = true;
}

Process::~Process() { stop(); }

bool Process::alive() {
  if (running_ && waitpid(pid_, &status_, WNOHANG) == pid_) running_ = false;
  return running_;
}

std::optional<int> Process::wait(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (alive()) {
    if (std::chrono::steady_clock::now() > deadline) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return exitCode();
}

int Process::wait() {
  if (running_) {
    while (waitpid(pid_, &status_, 0) < 0 && errno == EINTR) {
    }
    running_ = false;
  }
  return exitCode();
}

int Process::stop(std::chrono::milliseconds grace, const std::function<void()>& on_kill) {
  if (!alive()) return exitCode();
  kill(pid_, SIGTERM);
  if (const auto code = wait(grace)) return *code;
  if (on_kill) on_kill();
  kill(pid_, SIGKILL);
  return wait();
}

int Process::exitCode() const noexcept {
  if (WIFEXITED(status_)) return WEXITSTATUS(status_);
  if (WIFSIGNALED(status_)) return 128 + WTERMSIG(status_);
  return -1;
}

std::string Process::describeExit() const {
  if (WIFEXITED(status_)) return "exited with status " + std::to_string(WEXITSTATUS(status_));
  if (WIFSIGNALED(status_)) return std::string("killed by ") + strsignal(WTERMSIG(status_));
  return "ended";
}

}  // namespace telehand::app
