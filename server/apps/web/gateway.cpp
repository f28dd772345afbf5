#include "gateway.h"

#include <arpa/inet.h>
#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <random>
#include <vector>

#include "frames.h"
#include "replay.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/protocol/lesson_plan.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/sim/hand_model.h"
#include "telehand/server/store/open_store.h"

namespace telehand::web {

namespace {

constexpr int64_t kRateWindowNs = 1'000'000'000;
constexpr int64_t kListPeriodNs = 1'000'000'000;  // the session list to each browser
constexpr int64_t kListRebuildNs = 250'000'000;
constexpr std::size_t kEventsKept = 64;
constexpr std::size_t kSessionsKept = 512;  // ended ones beyond this are forgotten, oldest first
constexpr uint16_t kCloseTooBig = 1009;
constexpr uint16_t kCloseTryLater = 1013;
constexpr uint16_t kClosePolicy = 1008;

int64_t steadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

double ms(int64_t ns) { return static_cast<double>(ns) * 1e-6; }

// civetweb's C callbacks: the Gateway is the callback data.
int connectCb(const mg_connection* conn, void* g) {
  return static_cast<Gateway*>(g)->onConnect(const_cast<mg_connection*>(conn));
}
void readyCb(mg_connection* c, void* g) { static_cast<Gateway*>(g)->onReady(c); }
int dataCb(mg_connection* c, int bits, char* data, size_t len, void* g) {
  return static_cast<Gateway*>(g)->onData(c, bits, data, len);
}
void closeCb(const mg_connection* c, void* g) { static_cast<Gateway*>(g)->onClose(c); }
int statsCb(mg_connection* c, void* g) {
  const std::string body = static_cast<Gateway*>(g)->statsJson();
  mg_send_http_ok(c, "application/json", static_cast<long long>(body.size()));
  mg_write(c, body.data(), body.size());
  return 200;
}

/// A lesson run whose plan (SessionStatus.lesson) lets a supervisor take over.
bool takeoverAllowed(const telehand_msg_SessionStatus& st) {
  if (st.mode != telehand_msg_MODE_LESSON || st.state != telehand_msg_SESSION_ACTIVE) return false;
  const auto plan = decodePlan(std::string(st.lesson, strnlen(st.lesson, sizeof st.lesson)));
  return plan && plan->takeover;
}

int handCb(mg_connection* c, void* path) {
  mg_send_mime_file(c, static_cast<const std::string*>(path)->c_str(), "application/xml");
  return 200;
}

}  // namespace

struct Gateway::Client {
  uint64_t id = 0;
  mg_connection* conn = nullptr;
  std::mutex m;
  std::condition_variable cv;
  bool served = false;      // counted in served_ (set once, under clients_mutex_)
  bool closing = false;     // the connection is going: the writer ends
  uint16_t close_code = 0;  // the writer closes the connection with this code (0: no)
  std::string close_reason;
  /// Going, or dropped: nothing more is sent to it or taken from it (`m` held).
  bool done() const noexcept { return closing || close_code != 0; }
  uint64_t watching = 0;
  std::deque<std::string> queue;
  std::size_t queued_bytes = 0;             // of `queue`
  std::shared_ptr<const std::string> hand;  // the newest HandState frame not yet sent
  int64_t next_hand_ns = 0;
  std::thread writer;
  std::mutex replay_m;                     // guards replay_thread
  std::thread replay_thread;               // sends the replay's hand (ReplayHandService)
  std::atomic<bool> replay_cancel{false};  // the replay's hand is no longer wanted
};

struct Gateway::Session {
  std::optional<telehand_msg_SessionStatus> status;
  std::optional<telehand_msg_HandState> hand;
  int64_t hand_rx_ns = 0;     // steady clock
  int64_t hand_delay_ns = 0;  // gateway wall clock - HandState source time
  uint64_t hand_gaps = 0;
  std::deque<int64_t> hand_rx;
  std::deque<std::string> events;  // frames, oldest first
};

Gateway::Gateway(const Options& options)
    : o_(options),
      gateway_id_(std::random_device{}() | (static_cast<uint64_t>(std::random_device{}()) << 32)),
      participant_(o_.dds),
      topics_(participant_),
      status_reader_(participant_, topics_.session_status, dds::qos::sessionStatus()),
      hand_reader_(participant_, topics_.hand_state, dds::qos::handStateReader(4)),
      event_reader_(participant_, topics_.session_event, dds::qos::sessionEvent()),
      command_writer_(participant_, topics_.session_command, dds::qos::sessionCommand()),
      wake_(participant_),
      waitset_(participant_) {
  // HandState.joint_angles_rad's order is the hand model's (the server's --list-dofs): the
  // page is told the names rather than guessing the order from the URDF.
  hand_model_ =
      std::make_unique<const server::sim::HandModel>(server::sim::HandModel::load(o_.hand));
  std::string dofs;
  for (const auto& n : hand_model_->dofNames()) {
    dofs += (dofs.empty() ? "" : ",") + jsonString(n);
  }
  dofs_json_ = "[" + dofs + "]";
  ReplayHandOptions ho;
  ho.cases_dir = o_.cases;
  ho.hz = o_.replay_hand_hz;
  ho.min_hz = std::min(10.0, o_.replay_hand_hz);
  ho.max_frames = o_.replay_hand_frames;
  ho.max_s = o_.replay_hand_s;
  replay_hands_ = std::make_unique<ReplayHandService>(o_.db, *hand_model_, ho, o_.replay_hand_jobs,
                                                      o_.replay_cache_bytes);
  waitset_.attach(status_reader_.handle(), 1);
  waitset_.attach(hand_reader_.handle(), 2);
  waitset_.attach(event_reader_.handle(), 3);
  waitset_.attach(wake_.handle(), 4);

  mg_init_library(0);
  if (mg_check_feature(16) == 0) {
    throw ConfigError("this civetweb was built without WebSocket support");
  }
  const std::string threads = std::to_string(o_.max_clients + 8);
  // civetweb's websocket timeout is only how long a read waits: without its pings a peer that
  // vanished without a FIN (a laptop closed, a cable pulled) would hold a thread and a place
  // under --max-clients for good. With them it is let go after 6 pings without an answer.
  const std::string ping_ms =
      std::to_string(static_cast<long>(std::lround(std::max(o_.ping_s, 0.1) * 1000.0)));
  const char* opts[] = {"listening_ports",
                        o_.bind.c_str(),
                        "document_root",
                        o_.root.c_str(),
                        "num_threads",
                        threads.c_str(),
                        "enable_directory_listing",
                        "no",
                        "request_timeout_ms",
                        "10000",
                        "websocket_timeout_ms",
                        ping_ms.c_str(),
                        "enable_websocket_ping_pong",
                        "yes",
                        "additional_header",
                        "Cache-Control: no-cache",
                        nullptr};
  mg_callbacks callbacks{};
  callbacks.begin_request = [](mg_connection* c) {
    return static_cast<Gateway*>(mg_get_user_data(mg_get_context(c)))->onRequest(c);
  };
  callbacks.log_message = [](const mg_connection*, const char* message) {
    spdlog::warn("http: {}", message);
    return 1;
  };
  http_ = mg_start(&callbacks, this, opts);
  if (!http_) {
    mg_exit_library();
    throw ConfigError(
        fmt::format("cannot serve on '{}' (in use, or not an address:port?)", o_.bind));
  }
  mg_set_websocket_handler(http_, "/ws", connectCb, readyCb, dataCb, closeCb, this);
  mg_set_request_handler(http_, "/api/stats", statsCb, this);
  mg_set_request_handler(http_, "/hand.urdf$", handCb, &o_.hand);
}

Gateway::~Gateway() {
  mg_stop(http_);  // closes every connection: onClose joins each writer
  mg_exit_library();
}

int Gateway::port() const {
  mg_server_port ports[4]{};
  const int n = mg_get_server_ports(http_, 4, ports);
  return n > 0 ? ports[0].port : 0;
}

int Gateway::run(const std::atomic<bool>& stop) {
  std::thread dds([&] { ddsLoop(stop); });
  const auto t0 = std::chrono::steady_clock::now();
  while (!stop.load()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (o_.seconds > 0 &&
        std::chrono::steady_clock::now() - t0 > std::chrono::duration<double>(o_.seconds)) {
      break;
    }
  }
  stopping_.store(true);
  wake_.trigger();
  dds.join();
  return 0;
}

void Gateway::ddsLoop(const std::atomic<bool>& stop) {
  while (!stop.load() && !stopping_.load()) {
    waitset_.wait(std::chrono::milliseconds(500));
    wake_.clear();
    takeDds(steadyNs());
  }
}

void Gateway::takeDds(int64_t now_ns) {
  status_reader_.take(
      [&](const telehand_msg_SessionStatus& s, const dds_sample_info_t&) { onStatus(s); }, 256);
  event_reader_.take(
      [&](const telehand_msg_SessionEvent& e, const dds_sample_info_t&) { onEvent(e); }, 256);
  const int64_t wall = wallNs();
  stats_.hand_states += hand_reader_.take(
      [&](const telehand_msg_HandState& h, const dds_sample_info_t&) { onHand(h, wall, now_ns); },
      256);
}

void Gateway::onStatus(const telehand_msg_SessionStatus& s) {
  std::lock_guard lk(sessions_mutex_);
  auto& p = sessions_[s.session_id];
  if (!p) p = std::make_unique<Session>();
  p->status = s;
  ++sessions_version_;
  prune();
}

void Gateway::prune() {
  // Bounded however long it runs: sessions that are not active go first, lowest id first
  // (the server numbers sessions in order), then anything oldest.
  for (auto it = sessions_.begin(); sessions_.size() > kSessionsKept && it != sessions_.end();) {
    const auto& st = it->second->status;
    it = st && st->state == telehand_msg_SESSION_ACTIVE ? std::next(it) : sessions_.erase(it);
  }
  while (sessions_.size() > kSessionsKept) sessions_.erase(sessions_.begin());
}

void Gateway::onEvent(const telehand_msg_SessionEvent& e) {
  std::string frame = eventFrame(e);
  {
    std::lock_guard lk(sessions_mutex_);
    auto& p = sessions_[e.session_id];
    if (!p) p = std::make_unique<Session>();
    p->events.push_back(frame);
    if (p->events.size() > kEventsKept) p->events.pop_front();
    prune();
  }
  // To the browsers watching it; the server's errors not tied to a session to everyone.
  std::vector<std::shared_ptr<Client>> to;
  {
    std::lock_guard lk(clients_mutex_);
    for (const auto& [conn, c] : clients_) to.push_back(c);
  }
  for (const auto& c : to) {
    bool wants = false;
    {
      std::lock_guard lk(c->m);
      wants = c->watching == e.session_id || e.session_id == 0;
    }
    if (wants) push(*c, frame);
  }
}

void Gateway::onHand(const telehand_msg_HandState& h, int64_t wall_ns, int64_t now_ns) {
  {
    std::lock_guard lk(sessions_mutex_);
    auto it = sessions_.find(h.session_id);
    if (it == sessions_.end()) {
      sessions_.emplace(h.session_id, std::make_unique<Session>());
      prune();
      it = sessions_.find(h.session_id);
      if (it == sessions_.end()) return;  // no room for a session without a status
    }
    Session& s = *it->second;
    if (s.hand && h.seq <= s.hand->seq) return;  // reordered or repeated: the newer stands
    if (s.hand && h.seq > s.hand->seq + 1) s.hand_gaps += h.seq - s.hand->seq - 1;
    s.hand = h;
    s.hand_rx_ns = now_ns;
    s.hand_delay_ns = wall_ns - h.source_time_ns;
    s.hand_rx.push_back(now_ns);
    while (s.hand_rx.front() < now_ns - kRateWindowNs) s.hand_rx.pop_front();
  }
  // Serialized only when a browser watches this session: a session nobody watches costs a
  // take and a copy, nothing more.
  std::shared_ptr<const std::string> frame;
  std::lock_guard lk(clients_mutex_);
  for (const auto& [conn, c] : clients_) {
    std::lock_guard ck(c->m);
    if (c->watching != h.session_id || c->closing) continue;
    if (!frame) {
      frame = std::make_shared<const std::string>(handFrame(h, wall_ns));
      ++stats_.hand_frames;
    }
    if (c->hand) ++stats_.hand_coalesced;
    c->hand = frame;
    c->cv.notify_one();
  }
}

std::shared_ptr<const std::string> Gateway::sessionsFrame(int64_t now_ns) {
  std::lock_guard lk(sessions_mutex_);
  if (sessions_frame_ && sessions_frame_version_ == sessions_version_ &&
      now_ns - sessions_frame_ns_ < kListRebuildNs) {
    return sessions_frame_;
  }
  std::string out =
      fmt::format(R"({{"type":"sessions","now_ms":{:.3f},"sessions":[)", ms(wallNs()));
  bool first = true;
  for (auto it = sessions_.rbegin(); it != sessions_.rend(); ++it) {
    const Session& s = *it->second;
    if (!s.status) continue;
    const auto& st = *s.status;
    if (!first) out += ',';
    first = false;
    const std::size_t rate = std::count_if(s.hand_rx.begin(), s.hand_rx.end(),
                                           [&](int64_t t) { return t >= now_ns - kRateWindowNs; });
    fmt::format_to(std::back_inserter(out),
                   R"({{"id":{},"state":"{}","mode":"{}","user":{},"case":{},"started_ms":{:.3f},)"
                   R"("ended_ms":{:.3f},"samples":{},"missing":{},"hand_hz":{},"hand_gaps":{})",
                   it->first, stateName(st.state), modeName(st.mode), jsonString(st.user),
                   jsonString(st.case_name), ms(st.started_ns), ms(st.ended_ns),
                   st.samples_recorded, st.samples_missing, rate, s.hand_gaps);
    if (s.hand) {
      fmt::format_to(std::back_inserter(out),
                     R"(,"age_ms":{:.1f},"delay_ms":{:.1f},"dev_hz":{},"dev_lost":{},)"
                     R"("overruns":{},"model":{})",
                     ms(now_ns - s.hand_rx_ns), ms(s.hand_delay_ns),
                     jsonNumber(s.hand->device_rate_hz), s.hand->device_lost,
                     s.hand->device_overruns, s.hand->model_version);
    }
    if (takeoverAllowed(st)) out += R"(,"takeover":true)";
    out += '}';
  }
  fmt::format_to(std::back_inserter(out), R"(],"server_matched":{}}})",
                 hand_reader_.matchedWriters() > 0 ? "true" : "false");
  sessions_frame_ = std::make_shared<const std::string>(std::move(out));
  sessions_frame_ns_ = now_ns;
  sessions_frame_version_ = sessions_version_;
  return sessions_frame_;
}

bool Gateway::knownSession(uint64_t id) const {
  std::lock_guard lk(sessions_mutex_);
  const auto it = sessions_.find(id);
  return id != 0 && it != sessions_.end() && it->second->status.has_value();
}

// --- browsers ---

namespace {
/// Whether `origin` (a browser's Origin header) names the site at `host` (the Host header).
bool sameOrigin(std::string_view origin, const char* host_header) {
  // A browser names the page that opens a WebSocket in Origin; the console's own page comes
  // from the Host it connects to. The host compared without case.
  if (!host_header || !*host_header) return false;
  const std::string_view host(host_header);
  const auto same = [](char a, char b) {
    return std::tolower(static_cast<unsigned char>(a)) ==
           std::tolower(static_cast<unsigned char>(b));
  };
  for (const std::string_view scheme : {"http://", "https://"}) {
    if (origin.starts_with(scheme) && std::ranges::equal(origin.substr(scheme.size()), host, same))
      return true;
  }
  return false;
}

/// Whether a Host header names this console: no header (a program), an IP address (v4, or v6
/// in brackets), localhost, or a name of `allowed`; the port is not compared.
bool hostAllowed(const char* host_header, const std::vector<std::string>& allowed) {
  if (!host_header || !*host_header) return true;
  std::string_view host(host_header);
  if (host.front() == '[') return host.find(']') != std::string_view::npos;  // an IPv6 address
  host = host.substr(0, host.find(':'));
  std::string lower(host);
  for (char& ch : lower) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  if (lower == "localhost") return true;
  in_addr v4{};
  if (inet_pton(AF_INET, lower.c_str(), &v4) == 1) return true;
  for (const std::string& a : allowed) {
    std::string b = a;
    for (char& ch : b) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    if (b == lower) return true;
  }
  return false;
}

/// An HTTP answer to a WebSocket upgrade that is not taken: status and why, then the
/// connection closes (civetweb's own error page leaves the status line out here).
void refuse(mg_connection* conn, const char* status, const std::string& why) {
  mg_printf(conn,
            "HTTP/1.1 %s\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: "
            "%zu\r\nConnection: close\r\n\r\n%s",
            status, why.size(), why.c_str());
}
}  // namespace

int Gateway::onRequest(mg_connection* conn) {
  const char* host = mg_get_header(conn, "Host");
  if (hostAllowed(host, o_.allow_hosts)) return 0;
  ++stats_.foreign_host;
  spdlog::warn("refused a request for host '{}' (not an address, localhost or --allow-host)", host);
  refuse(conn, "403 Forbidden",
         fmt::format("telehand-web: this console is not served as '{}'; open it by its address, "
                     "as localhost, or start telehand-web with --allow-host NAME",
                     host));
  return 1;
}

int Gateway::onConnect(mg_connection* conn) {
  // A page of another site that the supervisor's browser has open may open a WebSocket here
  // too, and would act with the console's DDS identity: only the console's own page (or a
  // program, which sends no Origin) is served.
  const char* origin = mg_get_header(conn, "Origin");
  if (origin && !sameOrigin(origin, mg_get_header(conn, "Host"))) {
    ++stats_.clients_refused;
    ++stats_.foreign_origin;
    spdlog::warn(
        "refused a WebSocket opened by a page of {} (the console serves its own page "
        "only)",
        origin);
    refuse(conn, "403 Forbidden",
           fmt::format("telehand-web: a WebSocket from a page of {} is refused; open the "
                       "console's own page",
                       origin));
    return 1;
  }
  std::lock_guard lk(clients_mutex_);
  if (served_ >= o_.max_clients) {
    ++stats_.clients_refused;
    spdlog::warn("refused a browser: {} connected, the limit (--max-clients)", served_);
    refuse(conn, "503 Service Unavailable",
           fmt::format("telehand-web: {} browsers are connected, the limit (--max-clients); "
                       "try again when one leaves",
                       served_));
    return 1;
  }
  return 0;
}

void Gateway::onReady(mg_connection* conn) {
  auto c = std::make_shared<Client>();
  c->conn = conn;
  std::size_t others = 0;
  {
    std::lock_guard lk(clients_mutex_);
    c->id = next_client_++;
    others = served_;
    c->served = served_ < o_.max_clients;
    if (c->served) {
      ++served_;
      ++stats_.clients_open;  // under the lock: never above the limit, even for a moment
      ++stats_.clients_total;
    }
    clients_[conn] = c;
  }
  const mg_request_info* ri = mg_get_request_info(conn);
  if (!c->served) {
    // Upgrades that arrived together all passed onConnect's count before any was added: the
    // ones past the limit are closed at once ("try again later"), with their thread freed.
    ++stats_.clients_refused;
    spdlog::warn("refused browser {} from {}: {} connected, the limit (--max-clients)", c->id,
                 ri ? ri->remote_addr : "?", others);
    std::lock_guard lk(c->m);
    c->close_code = kCloseTryLater;
    c->close_reason = "too many browsers (--max-clients); try again when one leaves";
  } else {
    spdlog::info("browser {} connected from {}", c->id, ri ? ri->remote_addr : "?");
  }
  push(*c, fmt::format(R"({{"type":"hello","client":{},"hand_hz":{},"band":[{},{}],)"
                       R"("max_message":{},"replay":{},"domain":{},"partition":{},"dofs":{}}})",
                       c->id, o_.hand_hz, o_.band_min_n, o_.band_max_n, o_.max_message,
                       o_.db.empty() ? "false" : "true", o_.dds.domain,
                       jsonString(o_.dds.partition), dofs_json_));
  ++stats_.writer_threads;
  c->writer = std::thread([this, c] {
    writerLoop(c);
    --stats_.writer_threads;
  });
}

void Gateway::onClose(const mg_connection* conn) {
  std::shared_ptr<Client> c;
  {
    std::lock_guard lk(clients_mutex_);
    const auto it = clients_.find(conn);
    if (it == clients_.end()) return;
    c = it->second;
    clients_.erase(it);
    if (c->served) {
      --served_;
      --stats_.clients_open;
    }
  }
  {
    std::lock_guard lk(c->m);
    c->closing = true;
    c->queue.clear();
    c->queued_bytes = 0;
    c->hand.reset();
  }
  c->cv.notify_one();
  if (c->writer.joinable()) c->writer.join();
  stopReplayHand(*c);
  spdlog::info("browser {} gone", c->id);
}

bool Gateway::push(Client& c, std::string frame) {
  {
    std::lock_guard lk(c.m);
    if (c.done()) return false;
    if (c.queue.size() >= o_.queue_depth || c.queued_bytes + frame.size() > o_.queue_bytes) {
      // A browser that does not read: dropped, never waited for.
      ++stats_.dropped_slow;
      c.queue.clear();
      c.queued_bytes = 0;
      c.close_code = kClosePolicy;
      c.close_reason = "too slow: the gateway's queue for this browser is full";
      spdlog::warn("browser {}: {}", c.id, c.close_reason);
    } else {
      c.queued_bytes += frame.size();
      c.queue.push_back(std::move(frame));
    }
  }
  c.cv.notify_one();
  return true;
}

void Gateway::writerLoop(const std::shared_ptr<Client>& cp) {
  Client& c = *cp;
  const auto hand_period = static_cast<int64_t>(1e9 / o_.hand_hz);
  int64_t next_list = 0;
  std::vector<std::string> batch;
  for (;;) {
    std::shared_ptr<const std::string> hand;
    uint16_t close_code = 0;
    std::string close_reason;
    bool list = false;
    {
      std::unique_lock lk(c.m);
      for (;;) {
        const int64_t now = steadyNs();
        if (c.closing) return;
        if (c.close_code != 0 || !c.queue.empty() || now >= next_list ||
            (c.hand && now >= c.next_hand_ns)) {
          break;
        }
        int64_t until = next_list;
        if (c.hand) until = std::min(until, c.next_hand_ns);
        c.cv.wait_for(lk, std::chrono::nanoseconds(until - now));
      }
      const int64_t now = steadyNs();
      batch.assign(std::make_move_iterator(c.queue.begin()),
                   std::make_move_iterator(c.queue.end()));
      c.queue.clear();
      c.queued_bytes = 0;
      if (c.hand && now >= c.next_hand_ns) {
        hand = std::move(c.hand);
        c.hand.reset();
        c.next_hand_ns = std::max(c.next_hand_ns + hand_period, now);
      }
      if (now >= next_list) {
        list = true;
        next_list = now + kListPeriodNs;
      }
      close_code = c.close_code;
      close_reason = c.close_reason;
    }
    // Writing blocks this browser's thread only; the DDS thread replaces `hand` meanwhile.
    auto send = [&](const std::string& s) {
      return mg_websocket_write(c.conn, MG_WEBSOCKET_OPCODE_TEXT, s.data(), s.size()) > 0;
    };
    bool ok = true;
    for (const auto& s : batch) ok = ok && send(s);
    if (ok && hand) {
      ok = send(*hand);
      ++stats_.hand_sent;
    }
    if (ok && list) ok = send(*sessionsFrame(steadyNs()));
    if (!ok && close_code == 0) {
      // The connection failed under the write (a browser that stopped reading for civetweb's
      // timeout, a reset): said and counted, as a drop for a full queue is.
      ++stats_.write_failed;
      spdlog::warn("browser {}: a write failed; the browser is dropped", c.id);
    }
    if (close_code != 0 || !ok) {
      if (close_code != 0) {
        std::string payload(2, '\0');
        payload[0] = static_cast<char>(close_code >> 8);
        payload[1] = static_cast<char>(close_code & 0xff);
        payload += close_reason.substr(0, 120);
        mg_websocket_write(c.conn, MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE, payload.data(),
                           payload.size());
      }
      std::unique_lock lk(c.m);
      c.closing = true;  // nothing more to this browser; onClose frees it
      return;
    }
  }
}

int Gateway::onData(mg_connection* conn, int bits, const char* data, std::size_t len) {
  std::shared_ptr<Client> c;
  {
    std::lock_guard lk(clients_mutex_);
    const auto it = clients_.find(conn);
    if (it == clients_.end()) return 0;
    c = it->second;
  }
  const int opcode = bits & 0x0f;
  if (opcode == MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE) return 0;
  {
    // A browser already dropped (too slow, a failed write, a message too big): nothing more
    // is taken from it, and returning 0 ends the connection, which frees its place.
    std::lock_guard lk(c->m);
    if (c->done()) return 0;
  }
  if (opcode == MG_WEBSOCKET_OPCODE_PING || opcode == MG_WEBSOCKET_OPCODE_PONG) return 1;
  ++stats_.messages_in;
  if (len > o_.max_message) {
    ++stats_.bad_messages;
    push(*c, errorFrame("oversized", fmt::format("a message of {} bytes; the limit is {} bytes",
                                                 len, o_.max_message)));
    std::lock_guard lk(c->m);
    c->close_code = kCloseTooBig;
    c->close_reason = "message too big";
    c->cv.notify_one();
    return 1;  // the writer sends the error, then closes
  }
  if ((bits & 0x80) == 0 || opcode == MG_WEBSOCKET_OPCODE_CONTINUATION) {
    ++stats_.bad_messages;
    push(*c, errorFrame("malformed", "fragmented messages are not accepted"));
    return 1;
  }
  if (opcode != MG_WEBSOCKET_OPCODE_TEXT) {
    ++stats_.bad_messages;
    push(*c, errorFrame("malformed", "binary messages are not accepted: send JSON text"));
    return 1;
  }
  handle(c, std::string_view(data, len));
  return 1;
}

void Gateway::handle(const std::shared_ptr<Client>& c, std::string_view text) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    ++stats_.bad_messages;
    push(*c, errorFrame("malformed", fmt::format("not JSON: {}", e.what())));
    return;
  }
  if (!j.is_object()) {
    ++stats_.bad_messages;
    push(*c, errorFrame("malformed", fmt::format("not a JSON object but {}", j.type_name())));
    return;
  }
  const auto op = j.find("op");
  if (op == j.end() || !op->is_string()) {
    ++stats_.bad_messages;
    push(*c, errorFrame("malformed", "no \"op\" string"));
    return;
  }
  const std::string name = op->get<std::string>();
  std::optional<uint64_t> session;
  if (const auto s = j.find("session"); s != j.end()) {
    if (s->is_number_unsigned()) {
      session = s->get<uint64_t>();
    } else if (s->is_string()) {
      // Digits only, the whole string, within 64 bits: from_chars takes no sign, space or
      // "+" (stoull took "-5" as 2^64 - 5).
      const std::string& str = s->get_ref<const std::string&>();
      uint64_t id = 0;
      const auto [end, ec] = std::from_chars(str.data(), str.data() + str.size(), id);
      if (ec == std::errc{} && end == str.data() + str.size()) session = id;
    }
    if (!session) {
      ++stats_.bad_messages;
      std::string given = s->dump();
      if (given.size() > 40) given = given.substr(0, 40) + "...";
      push(*c, errorFrame("malformed", fmt::format("\"session\" is not a session id: {}", given)));
      return;
    }
  }
  auto needSession = [&]() {
    if (session) return true;
    ++stats_.bad_messages;
    push(*c, errorFrame("malformed", "\"" + name + "\" needs a \"session\" id"));
    return false;
  };
  if (name == "ping") {
    const auto t = j.find("t");
    // The page's time back as it sent it (a tab open for hours sends 10^7 ms and more).
    const bool given = t != j.end() && t->is_number() && std::isfinite(t->get<double>());
    push(*c, fmt::format(R"({{"type":"pong","t":{},"now_ms":{:.3f}}})",
                         given ? fmt::format("{}", t->get<double>()) : "null", ms(wallNs())));
  } else if (name == "watch") {
    if (needSession()) watch(c, *session);
  } else if (name == "mark") {
    if (!needSession()) return;
    const auto t = j.find("text");
    if (t == j.end() || !t->is_string()) {
      ++stats_.bad_messages;
      push(*c, errorFrame("malformed", "\"mark\" needs a \"text\" string"));
      return;
    }
    std::optional<double> at;
    if (const auto a = j.find("at_s"); a != j.end() && a->is_number()) at = a->get<double>();
    mark(*c, *session, t->get<std::string>(), at);
  } else if (name == "takeover") {
    if (!needSession()) return;
    // "from": the supervisor's own live session that leads the guide; absent or 0 gives the
    // guide back to the lesson's demonstration.
    uint64_t from = 0;
    if (const auto f = j.find("from"); f != j.end() && !f->is_null()) {
      if (!f->is_number_unsigned()) {
        ++stats_.bad_messages;
        push(*c, errorFrame("malformed", "\"from\" is not a session id"));
        return;
      }
      from = f->get<uint64_t>();
    }
    takeover(*c, *session, from);
  } else if (name == "replay") {
    if (needSession()) replay(c, *session);
  } else if (name == "records") {
    records(*c);
  } else {
    ++stats_.bad_messages;
    push(*c, errorFrame("unknown_op", "unknown op \"" + name.substr(0, 40) + "\""));
  }
}

void Gateway::watch(const std::shared_ptr<Client>& c, uint64_t session) {
  // Back to live: a replay's hand still being computed for this browser is no longer wanted
  // (it would hold the replays' worker and queue megabytes ahead of the live frames).
  stopReplayHand(*c);
  if (session != 0 && !knownSession(session)) {
    ++stats_.unknown_session;
    push(*c, errorFrame("unknown_session", fmt::format("no session {} on domain {} partition {}",
                                                       session, o_.dds.domain, o_.dds.partition)));
    return;
  }
  std::vector<std::string> history;
  std::shared_ptr<const std::string> hand;
  {
    std::lock_guard lk(sessions_mutex_);
    if (const auto it = sessions_.find(session); it != sessions_.end()) {
      history.assign(it->second->events.begin(), it->second->events.end());
      if (it->second->hand) {
        hand = std::make_shared<const std::string>(handFrame(*it->second->hand, wallNs()));
      }
    }
  }
  {
    std::lock_guard lk(c->m);
    c->watching = session;
    c->hand = hand;
  }
  push(*c, fmt::format(R"({{"type":"watching","session":{}}})", session));
  for (auto& e : history) push(*c, std::move(e));
}

void Gateway::mark(Client& c, uint64_t session, const std::string& text,
                   std::optional<double> at_s) {
  if (!knownSession(session)) {
    ++stats_.unknown_session;
    push(c, errorFrame("unknown_session",
                       fmt::format("no session {} to mark on domain {} partition {}", session,
                                   o_.dds.domain, o_.dds.partition)));
    return;
  }
  std::string clean;
  for (const char ch : text) clean += (static_cast<unsigned char>(ch) < 0x20) ? ' ' : ch;
  while (!clean.empty() && clean.back() == ' ') clean.pop_back();
  while (!clean.empty() && clean.front() == ' ') clean.erase(clean.begin());
  if (at_s && std::isfinite(*at_s) && *at_s >= 0) {
    clean = fmt::format("at {:.1f} s: {}", *at_s, clean);
  }
  constexpr std::size_t kMax = sizeof(telehand_msg_SessionCommand::text) - 1;
  if (clean.empty() || clean.size() > kMax) {
    ++stats_.bad_messages;
    push(c, errorFrame("bad_request", fmt::format("a mark is 1 to {} bytes of text", kMax)));
    return;
  }
  telehand_msg_SessionCommand cmd{};
  cmd.kind = telehand_msg_CMD_MARK;
  cmd.session_id = session;
  copyString(cmd.text, clean);
  if (!sendCommand(cmd)) {
    push(c, errorFrame("dds", "the mark could not be written to DDS"));
    return;
  }
  ++stats_.marks;
  spdlog::info("browser {} marked session {}: {}", c.id, session, clean);
  push(c, fmt::format(R"({{"type":"ack","op":"mark","session":{},"text":{}}})", session,
                      jsonString(clean)));
}

bool Gateway::sendCommand(telehand_msg_SessionCommand& cmd) {
  std::lock_guard lk(command_mutex_);
  cmd.client_id = gateway_id_;
  cmd.request_seq = ++request_seq_;
  cmd.source_time_ns = wallNs();
  return command_writer_.write(cmd) >= 0;
}

void Gateway::takeover(Client& c, uint64_t session, uint64_t from) {
  std::string why;
  bool unknown = false;
  {
    std::lock_guard lk(sessions_mutex_);
    const auto it = sessions_.find(session);
    const auto src = from ? sessions_.find(from) : sessions_.end();
    if (it == sessions_.end() || !it->second->status) {
      unknown = true;
      why = fmt::format("no session {} on domain {} partition {}", session, o_.dds.domain,
                        o_.dds.partition);
    } else if (!takeoverAllowed(*it->second->status)) {
      why = fmt::format("session {} is not a lesson run that allows a take-over", session);
    } else if (from != 0 && (src == sessions_.end() || !src->second->status ||
                             src->second->status->state != telehand_msg_SESSION_ACTIVE ||
                             src->second->status->mode != telehand_msg_MODE_MOBILIZATION)) {
      why = fmt::format("session {} is not an open mobilization at an MF-2", from);
    } else if (from == session) {
      why = "a session cannot lead itself";
    }
  }
  if (!why.empty()) {
    ++(unknown ? stats_.unknown_session : stats_.bad_messages);
    push(c, errorFrame(unknown ? "unknown_session" : "bad_request", why));
    return;
  }
  telehand_msg_SessionCommand cmd{};
  cmd.kind = telehand_msg_CMD_TAKEOVER;
  cmd.session_id = session;
  cmd.follow_session = from;
  if (!sendCommand(cmd)) {
    push(c, errorFrame("dds", "the take-over could not be written to DDS"));
    return;
  }
  ++stats_.takeovers;
  spdlog::info("browser {}: session {} {}", c.id, session,
               from ? fmt::format("taken over from session {}", from) : "given back");
  push(c, fmt::format(R"({{"type":"ack","op":"takeover","session":{},"from":{},"text":{}}})",
                      session, from,
                      jsonString(from ? fmt::format("take-over from session {} asked", from)
                                      : "give-back asked")));
}

void Gateway::replay(const std::shared_ptr<Client>& cp, uint64_t session) {
  Client& c = *cp;
  stopReplayHand(c);  // the hand of the replay before sends nothing after this one's frame
  if (o_.db.empty()) {
    push(c, errorFrame("no_store", "this gateway has no record store (--db)"));
    return;
  }
  try {
    auto frame = replayFrame(o_.db, session, o_.replay_points);
    if (!frame) {
      ++stats_.unknown_session;
      push(c, errorFrame("unknown_session", fmt::format("no session {} in {}", session,
                                                        server::store::describeStore(o_.db))));
      return;
    }
    ++stats_.replays;
    push(c, std::move(*frame));
  } catch (const std::exception& e) {
    spdlog::warn("browser {}: replay of session {}: {}", c.id, session, e.what());
    push(c, errorFrame("store", fmt::format("replay of session {}: {}", session, e.what())));
    return;
  }
  startReplayHand(cp, session);
}

// --- a replay's hand ---

void Gateway::startReplayHand(const std::shared_ptr<Client>& c, uint64_t session) {
  stopReplayHand(*c);  // the one this browser asked for before, if still running
  if (stopping_.load()) return;
  std::lock_guard lk(c->replay_m);
  ++stats_.replay_workers;
  c->replay_thread = std::thread([this, c, session] {
    replay_hands_->run(
        session, [&](std::string frame) { push(*c, std::move(frame)); },
        [&] {
          if (c->replay_cancel.load() || stopping_.load()) return true;
          std::lock_guard ck(c->m);
          return c->done();
        });
    --stats_.replay_workers;
  });
}

void Gateway::stopReplayHand(Client& c) {
  std::thread t;
  {
    std::lock_guard lk(c.replay_m);
    t = std::move(c.replay_thread);
  }
  if (!t.joinable()) return;
  c.replay_cancel.store(true);
  replay_hands_->wake();
  t.join();  // it stops within one frame's steps (a few ms)
  c.replay_cancel.store(false);
}

void Gateway::records(Client& c) {
  if (o_.db.empty()) {
    push(c, errorFrame("no_store", "this gateway has no record store (--db)"));
    return;
  }
  try {
    push(c, recordsFrame(o_.db));
  } catch (const std::exception& e) {
    spdlog::warn("browser {}: the list of records: {}", c.id, e.what());
    push(c, errorFrame("store", fmt::format("the list of records: {}", e.what())));
  }
}

std::string Gateway::statsJson() const {
  std::size_t sessions = 0;
  {
    std::lock_guard lk(sessions_mutex_);
    sessions = sessions_.size();
  }
  return fmt::format(
      R"({{"clients_open":{},"clients_total":{},"clients_refused":{},"foreign_origin":{},)"
      R"("writer_threads":{},)"
      R"("sessions":{},"hand_states":{},"hand_frames":{},"hand_sent":{},"hand_coalesced":{},)"
      R"("messages_in":{},"bad_messages":{},"unknown_session":{},"marks":{},"replays":{},)"
      R"("takeovers":{},"dropped_slow":{},"replay_hands":{},"replay_hand_frames":{},)"
      R"("replay_hand_cached":{},"replay_workers":{},"write_failed":{},"foreign_host":{}}})",
      stats_.clients_open.load(), stats_.clients_total.load(), stats_.clients_refused.load(),
      stats_.foreign_origin.load(), stats_.writer_threads.load(), sessions,
      stats_.hand_states.load(), stats_.hand_frames.load(), stats_.hand_sent.load(),
      stats_.hand_coalesced.load(), stats_.messages_in.load(), stats_.bad_messages.load(),
      stats_.unknown_session.load(), stats_.marks.load(), stats_.replays.load(),
      stats_.takeovers.load(), stats_.dropped_slow.load(), replay_hands_->hands.load(),
      replay_hands_->frames.load(), replay_hands_->cached.load(), stats_.replay_workers.load(),
      stats_.write_failed.load(), stats_.foreign_host.load());
}

}  // namespace telehand::web
