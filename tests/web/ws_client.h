#pragma once
// A WebSocket client of telehand-web for tests and the benchmark: civetweb's client API,
// the frames it receives kept in order (or only counted), plus a raw socket that upgrades
// and vanishes without a close frame, as a killed tab does.
#include <arpa/inet.h>
#include <civetweb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace telehand::test {

class WsClient {
 public:
  /// Connects to ws://127.0.0.1:`port`/ws; `keep` false: frames are counted, not kept.
  explicit WsClient(int port, bool keep = true) : keep_(keep) {
    char err[256] = {0};
    conn_ = mg_connect_websocket_client("127.0.0.1", port, 0, err, sizeof err, "/ws", nullptr,
                                        &WsClient::onData, &WsClient::onClose, this);
    if (!conn_) error_ = err;
  }
  ~WsClient() { close(); }
  WsClient(const WsClient&) = delete;
  WsClient& operator=(const WsClient&) = delete;

  bool ok() const { return conn_ != nullptr; }
  const std::string& error() const { return error_; }

  bool send(const std::string& text, int opcode = MG_WEBSOCKET_OPCODE_TEXT) {
    return conn_ && mg_websocket_client_write(conn_, opcode, text.data(), text.size()) > 0;
  }
  /// As a browser closes a tab: a close frame, the gateway's answer (within 1 s), then the
  /// connection. Without the frame civetweb's reader thread only notices at its next read
  /// timeout, about a second later.
  void close() {
    if (!conn_) return;
    const char normal[2] = {0x03, static_cast<char>(0xE8)};  // 1000: normal closure
    if (!waitClosed(std::chrono::milliseconds(0)) &&
        mg_websocket_client_write(conn_, MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE, normal,
                                  sizeof normal) > 0)
      waitClosed(std::chrono::seconds(1));
    mg_close_connection(conn_);
    conn_ = nullptr;
  }

  /// The next frame containing `needle` (earlier ones are dropped), within `timeout`.
  std::optional<std::string> waitFor(const std::string& needle,
                                     std::chrono::milliseconds timeout = std::chrono::seconds(5)) {
    std::unique_lock lk(m_);
    const auto end = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      while (!frames_.empty()) {
        std::string f = std::move(frames_.front());
        frames_.pop_front();
        if (f.find(needle) != std::string::npos) return f;
      }
      if (cv_.wait_until(lk, end) == std::cv_status::timeout && frames_.empty()) return {};
    }
  }
  /// Frames containing each of `needles`, in whatever order they come (frames matching none
  /// are dropped), within `timeout`: one per needle, empty where none came. For replies whose
  /// order the gateway does not fix (an ack and the server's event it leads to).
  std::vector<std::string> waitForAll(const std::vector<std::string>& needles,
                                      std::chrono::milliseconds timeout) {
    std::vector<std::string> got(needles.size());
    std::size_t found = 0;
    std::unique_lock lk(m_);
    const auto end = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      while (!frames_.empty()) {
        std::string f = std::move(frames_.front());
        frames_.pop_front();
        for (std::size_t i = 0; i < needles.size(); ++i) {
          if (got[i].empty() && f.find(needles[i]) != std::string::npos) {
            got[i] = f;
            ++found;
            break;
          }
        }
        if (found == needles.size()) return got;
      }
      if (cv_.wait_until(lk, end) == std::cv_status::timeout && frames_.empty()) return got;
    }
  }
  /// True once the gateway closed the connection.
  bool waitClosed(std::chrono::milliseconds timeout) {
    std::unique_lock lk(m_);
    return cv_.wait_for(lk, timeout, [&] { return closed_; });
  }
  uint64_t frames() const {
    std::lock_guard lk(m_);
    return count_;
  }
  /// HandState frames received.
  uint64_t hands() const {
    std::lock_guard lk(m_);
    return hands_;
  }
  uint64_t bytes() const {
    std::lock_guard lk(m_);
    return bytes_;
  }

 private:
  static int onData(mg_connection* conn, int bits, char* data, size_t len, void* self) {
    auto* c = static_cast<WsClient*>(self);
    if ((bits & 0x0f) == MG_WEBSOCKET_OPCODE_PING) {
      // Answered as a browser answers them (civetweb's client leaves that to its user): the
      // gateway closes a browser that leaves its pings unanswered (--ping-s).
      mg_websocket_client_write(conn, MG_WEBSOCKET_OPCODE_PONG, data, len);
      return 1;
    }
    if ((bits & 0x0f) != MG_WEBSOCKET_OPCODE_TEXT) return 1;
    {
      std::lock_guard lk(c->m_);
      ++c->count_;
      c->bytes_ += len;
      if (std::string_view(data, len).starts_with(R"({"type":"hand")")) ++c->hands_;
      if (c->keep_) c->frames_.emplace_back(data, len);
    }
    c->cv_.notify_all();
    return 1;
  }
  static void onClose(const mg_connection*, void* self) {
    auto* c = static_cast<WsClient*>(self);
    {
      std::lock_guard lk(c->m_);
      c->closed_ = true;
    }
    c->cv_.notify_all();
  }

  bool keep_;
  mg_connection* conn_ = nullptr;
  std::string error_;
  mutable std::mutex m_;
  std::condition_variable cv_;
  std::deque<std::string> frames_;
  uint64_t count_ = 0, hands_ = 0, bytes_ = 0;
  bool closed_ = false;
};

/// A TCP connection to 127.0.0.1:`port` (-1 on failure); with `receive_buffer` > 0 the
/// socket's receive buffer is set that small first (a browser that reads slowly).
inline int connectLoopback(int port, int receive_buffer = 0) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return -1;
  if (receive_buffer > 0)
    ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &receive_buffer, sizeof receive_buffer);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

/// A WebSocket upgrade to 127.0.0.1:`port` with `headers` ("Name: value\r\n" each) besides
/// the handshake's own, on a connection of connectLoopback(port, receive_buffer); the
/// gateway's answer (its head and what came with it, "" if none), and the socket through
/// `fd_out` when it was upgraded (else closed and -1).
inline std::string upgradeWith(int port, const std::string& headers, int* fd_out = nullptr,
                               int receive_buffer = 0, const std::string& host = "") {
  if (fd_out) *fd_out = -1;
  const int fd = connectLoopback(port, receive_buffer);
  if (fd < 0) return "";
  const std::string req =
      "GET /ws HTTP/1.1\r\nHost: " + (host.empty() ? "127.0.0.1:" + std::to_string(port) : host) +
      "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
      "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: "
      "13\r\n" +
      headers + "\r\n";
  std::string answer;
  if (::write(fd, req.data(), req.size()) == static_cast<ssize_t>(req.size())) {
    // The whole head (the first frames may follow it in the same read), within 5 s.
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (answer.find("\r\n\r\n") == std::string::npos &&
           std::chrono::steady_clock::now() < until) {
      pollfd p{fd, POLLIN, 0};
      if (::poll(&p, 1, 100) <= 0) continue;
      char buf[1024];
      const ssize_t n = ::read(fd, buf, sizeof buf);
      if (n <= 0) break;
      answer.append(buf, static_cast<std::size_t>(n));
    }
  }
  if (fd_out && answer.find(" 101 ") != std::string::npos) {
    *fd_out = fd;
  } else {
    ::close(fd);
  }
  return answer;
}

/// Opens a WebSocket by hand and returns the socket once upgraded (-1 on failure); the
/// caller close()s it without a close frame.
inline int rawUpgrade(int port) {
  int fd = -1;
  upgradeWith(port, "", &fd);
  return fd;
}

/// Writes `text` to a raw WebSocket as one masked text frame (the mask all zero); false when
/// the write failed.
inline bool writeTextFrame(int fd, const std::string& text) {
  std::string f(1, static_cast<char>(0x81));
  if (text.size() < 126) {
    f += static_cast<char>(0x80 | text.size());
  } else {
    f += static_cast<char>(0x80 | 126);
    f += static_cast<char>((text.size() >> 8) & 0xff);
    f += static_cast<char>(text.size() & 0xff);
  }
  f.append(4, '\0');
  f += text;
  return ::write(fd, f.data(), f.size()) == static_cast<ssize_t>(f.size());
}

/// Reads what the gateway sends on a raw WebSocket `fd` for `for_time`; `pending` holds the
/// bytes not yet a whole frame (start it with what followed the upgrade's answer). Each ping
/// is answered with a pong, as a browser does by itself, when `answer_pings`. Returns the pings
/// read, or -1 once the gateway has closed the connection.
inline int readFrames(int fd, std::string& pending, bool answer_pings,
                      std::chrono::milliseconds for_time) {
  const auto until = std::chrono::steady_clock::now() + for_time;
  int pings = 0;
  for (;;) {
    // Whole frames first: FIN and opcode, a length of 7, 16 or 64 bits, no mask (server).
    while (pending.size() >= 2) {
      const auto byte = [&](std::size_t i) { return static_cast<uint8_t>(pending[i]); };
      std::size_t head = 2;
      uint64_t len = byte(1) & 0x7f;
      if (len == 126) {
        if (pending.size() < 4) break;
        len = (uint64_t{byte(2)} << 8) | byte(3);
        head = 4;
      } else if (len == 127) {
        if (pending.size() < 10) break;
        len = 0;
        for (std::size_t i = 2; i < 10; ++i) len = (len << 8) | byte(i);
        head = 10;
      }
      if (pending.size() < head + len) break;
      const int opcode = byte(0) & 0x0f;
      if (opcode == MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE) return -1;
      if (opcode == MG_WEBSOCKET_OPCODE_PING) {
        ++pings;
        if (answer_pings && len < 126) {
          std::string pong(1, static_cast<char>(0x80 | MG_WEBSOCKET_OPCODE_PONG));
          pong += static_cast<char>(0x80 | len);
          pong.append(4, '\0');  // the mask, all zero
          pong.append(pending, head, len);
          if (::write(fd, pong.data(), pong.size()) != static_cast<ssize_t>(pong.size())) return -1;
        }
      }
      pending.erase(0, head + len);
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        until - std::chrono::steady_clock::now());
    if (left.count() <= 0) return pings;
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
    char buf[4096];
    const ssize_t n = ::read(fd, buf, sizeof buf);
    if (n <= 0) return -1;
    pending.append(buf, static_cast<std::size_t>(n));
  }
}

/// GET `path` from 127.0.0.1:`port`; the body, or "" on failure.
inline std::string httpGet(int port, const std::string& path,
                           const std::string& host = "127.0.0.1") {
  char err[256] = {0};
  mg_connection* c = mg_download("127.0.0.1", port, 0, err, sizeof err,
                                 "GET %s HTTP/1.0\r\nHost: %s\r\n\r\n", path.c_str(), host.c_str());
  if (!c) return "";
  std::string body;
  char buf[4096];
  int n;
  while ((n = mg_read(c, buf, sizeof buf)) > 0) body.append(buf, static_cast<std::size_t>(n));
  mg_close_connection(c);
  return body;
}

}  // namespace telehand::test
