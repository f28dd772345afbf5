#pragma once
/// The OPENs a client sends to have its session resumed: one a second until a server takes
/// the session on (docs/recovery.md). A loaded server may answer one of them after the next
/// was sent; its answer counts all the same, or a server slower than a second to answer
/// would never be heard.
#include <cstdint>

namespace telehand::client::link {

class ResumeRequests {
 public:
  /// A resume begins: no request of it sent yet.
  void begin() noexcept { any_ = false; }
  /// A request of this resume went out with `request_seq`.
  void sent(uint32_t request_seq) noexcept {
    if (!any_) first_ = request_seq;
    last_ = request_seq;
    any_ = true;
  }
  /// Whether an answer naming `request_seq` answers a request of this resume (sequence
  /// numbers wrap: compared from the first).
  bool answers(uint32_t request_seq) const noexcept {
    return any_ &&
           static_cast<uint32_t>(request_seq - first_) <= static_cast<uint32_t>(last_ - first_);
  }

 private:
  uint32_t first_ = 0, last_ = 0;
  bool any_ = false;
};

}  // namespace telehand::client::link
