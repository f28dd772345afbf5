#pragma once
/// The record chunks a client has sent but its server has not yet acknowledged as stored
/// (SessionStatus.stored_below; docs/recovery.md): kept until then, so that a server that
/// dies or stops loses nothing. The newest `memory_chunks` stay in memory; older ones go to
/// an unlinked file (gone with the process), up to `max_file_bytes`; past that the oldest
/// are dropped and counted (the record will say they are missing). First in, first out.
#include <cstddef>
#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include "telehand.h"

namespace telehand::client::link {

class SpillQueue {
 public:
  using Chunk = std::vector<telehand_msg_DeviceState>;

  /// `dir`: where the spill file is made (created on first use; an Error names it when it
  /// cannot be).
  SpillQueue(std::size_t memory_chunks, uint64_t max_file_bytes, std::string dir);
  ~SpillQueue();
  SpillQueue(const SpillQueue&) = delete;
  SpillQueue& operator=(const SpillQueue&) = delete;

  void push(Chunk&& c);
  /// Take the oldest chunk; false when empty.
  bool pop(Chunk& out);
  /// Forget the oldest chunks whose every sample has seq < `below`.
  void forgetBelow(uint64_t below);

  std::size_t size() const noexcept { return mem_.size() + file_chunks_; }
  bool empty() const noexcept { return size() == 0; }
  std::size_t samples() const noexcept { return samples_; }
  std::size_t chunksOnDisk() const noexcept { return file_chunks_; }
  uint64_t bytesOnDisk() const noexcept { return tail_ - head_; }
  /// Samples dropped because the file was full (never sent again).
  uint64_t droppedSamples() const noexcept { return dropped_; }

 private:
  void spillOldest();
  bool readHead(Chunk& out, uint64_t& bytes);
  void openFile();

  std::size_t memory_chunks_;
  uint64_t max_file_bytes_;
  std::string dir_;
  std::deque<Chunk> mem_;  // the newest, oldest first
  int fd_ = -1;
  uint64_t head_ = 0, tail_ = 0;  // the file's oldest chunk and its end
  std::size_t file_chunks_ = 0;
  std::size_t samples_ = 0;
  uint64_t dropped_ = 0;
};

}  // namespace telehand::client::link
