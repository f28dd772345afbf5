#include "telehand/client/link/spill_queue.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

#include "telehand/core/error.h"

namespace telehand::client::link {

namespace {
// On disk: the sample count, then the samples as they are in memory (one process writes and
// reads them back).
struct Header {
  uint32_t count = 0;
  uint32_t reserved = 0;
};

void writeAll(int fd, const void* p, std::size_t n, uint64_t at, const std::string& dir) {
  const auto* b = static_cast<const char*>(p);
  while (n > 0) {
    const ssize_t w = ::pwrite(fd, b, n, static_cast<off_t>(at));
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) {
      throw Error("cannot keep unacknowledged samples in " + dir + ": " + std::strerror(errno));
    }
    b += w;
    n -= static_cast<std::size_t>(w);
    at += static_cast<uint64_t>(w);
  }
}

void readAll(int fd, void* p, std::size_t n, uint64_t at, const std::string& dir) {
  auto* b = static_cast<char*>(p);
  while (n > 0) {
    const ssize_t r = ::pread(fd, b, n, static_cast<off_t>(at));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) {
      throw Error("cannot read back unacknowledged samples from " + dir + ": " +
                  (r == 0 ? std::string("short file") : std::strerror(errno)));
    }
    b += r;
    n -= static_cast<std::size_t>(r);
    at += static_cast<uint64_t>(r);
  }
}
}  // namespace

SpillQueue::SpillQueue(std::size_t memory_chunks, uint64_t max_file_bytes, std::string dir)
    : memory_chunks_(memory_chunks), max_file_bytes_(max_file_bytes), dir_(std::move(dir)) {}

SpillQueue::~SpillQueue() {
  if (fd_ >= 0) ::close(fd_);
}

void SpillQueue::openFile() {
  if (fd_ >= 0) return;
  std::error_code ec;
  std::filesystem::create_directories(dir_, ec);
  fd_ = ::open(dir_.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd_ < 0) {
    // Filesystems without O_TMPFILE: a named file, unlinked at once.
    std::string path = dir_ + "/telehand-unacked-XXXXXX";
    fd_ = ::mkostemp(path.data(), O_CLOEXEC);
    if (fd_ >= 0) ::unlink(path.c_str());
  }
  if (fd_ < 0) {
    throw Error("cannot keep unacknowledged samples in " + dir_ + ": " + std::strerror(errno));
  }
}

void SpillQueue::push(Chunk&& c) {
  samples_ += c.size();
  mem_.push_back(std::move(c));
  while (mem_.size() > memory_chunks_) spillOldest();
}

void SpillQueue::spillOldest() {
  Chunk& c = mem_.front();
  const uint64_t bytes = sizeof(Header) + c.size() * sizeof(telehand_msg_DeviceState);
  if (max_file_bytes_ < bytes) {
    // No room on disk at all: the oldest in memory goes.
    dropped_ += c.size();
    samples_ -= c.size();
    mem_.pop_front();
    return;
  }
  openFile();
  while (file_chunks_ > 0 && tail_ - head_ + bytes > max_file_bytes_) {
    Chunk old;
    uint64_t old_bytes = 0;
    readHead(old, old_bytes);
    head_ += old_bytes;
    --file_chunks_;
    dropped_ += old.size();
    samples_ -= old.size();
  }
  if (file_chunks_ == 0) {
    // Empty: start the file again (keeps it from growing with what was read).
    head_ = tail_ = 0;
    if (::ftruncate(fd_, 0) != 0) {
      throw Error("cannot keep unacknowledged samples in " + dir_ + ": " + std::strerror(errno));
    }
  }
  Header h;
  h.count = static_cast<uint32_t>(c.size());
  writeAll(fd_, &h, sizeof h, tail_, dir_);
  writeAll(fd_, c.data(), c.size() * sizeof(telehand_msg_DeviceState), tail_ + sizeof h, dir_);
  tail_ += bytes;
  ++file_chunks_;
  mem_.pop_front();
}

bool SpillQueue::readHead(Chunk& out, uint64_t& bytes) {
  if (file_chunks_ == 0) return false;
  Header h;
  readAll(fd_, &h, sizeof h, head_, dir_);
  out.resize(h.count);
  readAll(fd_, out.data(), out.size() * sizeof(telehand_msg_DeviceState), head_ + sizeof h, dir_);
  bytes = sizeof h + out.size() * sizeof(telehand_msg_DeviceState);
  return true;
}

bool SpillQueue::pop(Chunk& out) {
  if (file_chunks_ > 0) {
    uint64_t bytes = 0;
    readHead(out, bytes);
    head_ += bytes;
    --file_chunks_;
  } else if (!mem_.empty()) {
    out = std::move(mem_.front());
    mem_.pop_front();
  } else {
    return false;
  }
  samples_ -= out.size();
  return true;
}

void SpillQueue::forgetBelow(uint64_t below) {
  Chunk c;
  while (file_chunks_ > 0) {
    uint64_t bytes = 0;
    readHead(c, bytes);
    if (!c.empty() && c.back().seq >= below) return;
    head_ += bytes;
    --file_chunks_;
    samples_ -= c.size();
  }
  while (!mem_.empty() && (mem_.front().empty() || mem_.front().back().seq < below)) {
    samples_ -= mem_.front().size();
    mem_.pop_front();
  }
}

}  // namespace telehand::client::link
