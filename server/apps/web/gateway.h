#pragma once
/// telehand-web's gateway: one DDS participant (the supervisor's role) whose thread keeps
/// what the sessions tell, and the browsers' WebSocket connections (civetweb), each with a
/// writer thread of its own, so that a slow browser stalls only itself (docs/web.md).
#include <civetweb.h>

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>

#include "replay_service.h"
#include "telehand/protocol/dds.h"
#include "telehand/server/sim/hand_model.h"

namespace telehand::web {

struct Options {
  dds::Options dds;
  std::string bind = "127.0.0.1:8080";  ///< civetweb listening_ports syntax
  /// Host names the console may be reached by besides IP addresses and localhost (a Host
  /// header naming another is refused: a page whose name was made to point here, DNS
  /// rebinding, is another site).
  std::vector<std::string> allow_hosts;
  std::string root;          ///< the page's files (index.html, vendor/, hand24.urdf)
  std::string db;            ///< the record store for replay ('' = no replay)
  std::string hand;          ///< the hand model (URDF) HandState's joints follow
  double hand_hz = 60.0;     ///< HandState frames per second per browser, at most
  double band_min_n = 12.0;  ///< reference force band shown on the plot
  double band_max_n = 16.0;
  std::size_t max_clients = 32;
  std::size_t max_message = 4096;       ///< largest message a browser may send, bytes
  std::size_t queue_depth = 512;        ///< messages waiting for one browser before it is dropped
  std::size_t queue_bytes = 16u << 20;  ///< ...or bytes (a replay is up to a few MB)
  /// Seconds a browser may be silent before the gateway pings it; after 6 pings without an
  /// answer (a browser answers them itself) the connection is closed and its place freed.
  double ping_s = 30.0;
  std::size_t replay_points = 24000;  ///< samples a replay sends at most (decimated evenly)
  /// A replay's hand (replay_hand.h): the patient cases the server reads, frames per second of
  /// record, frames in all and seconds of record at most, and how many run at once (each
  /// takes a core while it runs; more wait their turn).
  std::string cases;
  double replay_hand_hz = 50.0;
  std::size_t replay_hand_frames = 9000;
  double replay_hand_s = 600.0;
  std::size_t replay_hand_jobs = 1;
  std::size_t replay_cache_bytes = 64u << 20;  ///< replays' hands kept to send again
  double seconds = 0.0;                        ///< run this long (0 = until SIGINT/SIGTERM)
};

/// Counters /api/stats reports (tests and the benchmark read them).
struct Stats {
  std::atomic<uint64_t> clients_open{0};     ///< browsers served now (not those being refused)
  std::atomic<uint64_t> clients_total{0};    ///< browsers served since start
  std::atomic<uint64_t> clients_refused{0};  ///< over --max-clients, or a foreign page's
  std::atomic<uint64_t> foreign_origin{0};   ///< WebSockets opened by another site's page
  std::atomic<uint64_t> foreign_host{0};     ///< requests naming a host not allowed (--allow-host)
  std::atomic<uint64_t> hand_states{0};      ///< HandState taken from DDS
  std::atomic<uint64_t> hand_frames{0};      ///< HandState frames serialized (watched sessions)
  std::atomic<uint64_t> hand_sent{0};        ///< frames written to browsers
  std::atomic<uint64_t> hand_coalesced{0};   ///< frames replaced by a newer one before sending
  std::atomic<uint64_t> messages_in{0};
  std::atomic<uint64_t> bad_messages{0};  ///< malformed, oversized or unknown requests
  std::atomic<uint64_t> unknown_session{0};
  std::atomic<uint64_t> marks{0};
  std::atomic<uint64_t> takeovers{0};  ///< TAKEOVER commands sent
  std::atomic<uint64_t> replays{0};
  std::atomic<uint64_t> dropped_slow{0};    ///< browsers dropped for a full queue
  std::atomic<uint64_t> write_failed{0};    ///< browsers dropped for a failed write
  std::atomic<uint64_t> writer_threads{0};  ///< writer threads alive now
  std::atomic<uint64_t> replay_workers{0};  ///< threads sending a replay's hand now
};

class Gateway {
 public:
  explicit Gateway(const Options& options);
  ~Gateway();
  Gateway(const Gateway&) = delete;
  Gateway& operator=(const Gateway&) = delete;

  /// The port it serves on (the one the system chose when --bind asked for port 0).
  int port() const;

  /// Serves until `stop` or --seconds; returns the exit code.
  int run(const std::atomic<bool>& stop);

  // civetweb's callbacks (public for the C trampolines in gateway.cpp).
  int onConnect(mg_connection* conn);
  /// Every request: refused (403, 1) when its Host header names a host not allowed.
  int onRequest(mg_connection* conn);
  void onReady(mg_connection* conn);
  int onData(mg_connection* conn, int bits, const char* data, std::size_t len);
  void onClose(const mg_connection* conn);
  std::string statsJson() const;

 private:
  struct Client;
  struct Session;

  void ddsLoop(const std::atomic<bool>& stop);
  void takeDds(int64_t now_ns);
  void onHand(const telehand_msg_HandState& h, int64_t wall_ns, int64_t now_ns);
  void onStatus(const telehand_msg_SessionStatus& s);
  void onEvent(const telehand_msg_SessionEvent& e);
  /// Keeps at most 512 sessions (sessions_mutex_ held).
  void prune();
  /// The session list as a frame, rebuilt at most every 250 ms.
  std::shared_ptr<const std::string> sessionsFrame(int64_t now_ns);
  void writerLoop(const std::shared_ptr<Client>& c);
  /// Queues `frame` for `c`; false (and the client is closed) when its queue is full.
  bool push(Client& c, std::string frame);
  void handle(const std::shared_ptr<Client>& c, std::string_view text);
  void watch(const std::shared_ptr<Client>& c, uint64_t session);
  void mark(Client& c, uint64_t session, const std::string& text, std::optional<double> at_s);
  /// Asks the server that `from`'s live movement lead lesson run `session`'s guide (0: the
  /// demonstration again): a CMD_TAKEOVER, after the checks the gateway can make itself.
  void takeover(Client& c, uint64_t session, uint64_t from);
  /// Writes `cmd` as this gateway's next command (client id, request number, time filled
  /// in); false when DDS refused it.
  bool sendCommand(telehand_msg_SessionCommand& cmd);
  void replay(const std::shared_ptr<Client>& c, uint64_t session);
  /// Computes the replay's hand on a thread of the client's own, sending it as it goes.
  void startReplayHand(const std::shared_ptr<Client>& c, uint64_t session);
  /// Stops and joins the client's replay hand thread, if any.
  void stopReplayHand(Client& c);
  void records(Client& c);
  bool knownSession(uint64_t id) const;

  Options o_;
  Stats stats_;
  uint64_t gateway_id_;
  std::string dofs_json_;
  std::unique_ptr<const server::sim::HandModel> hand_model_;
  std::unique_ptr<ReplayHandService> replay_hands_;
  dds::Participant participant_;
  dds::Topics topics_;
  dds::Reader<telehand_msg_SessionStatus> status_reader_;
  dds::Reader<telehand_msg_HandState> hand_reader_;
  dds::Reader<telehand_msg_SessionEvent> event_reader_;
  dds::Writer<telehand_msg_SessionCommand> command_writer_;
  dds::GuardCondition wake_;
  dds::WaitSet waitset_;
  std::mutex command_mutex_;
  uint32_t request_seq_ = 0;

  mutable std::mutex sessions_mutex_;
  std::map<uint64_t, std::unique_ptr<Session>> sessions_;
  uint64_t sessions_version_ = 1;
  std::shared_ptr<const std::string> sessions_frame_;
  int64_t sessions_frame_ns_ = 0;
  uint64_t sessions_frame_version_ = 0;

  mutable std::mutex clients_mutex_;
  std::map<const mg_connection*, std::shared_ptr<Client>> clients_;
  uint64_t next_client_ = 1;
  std::size_t served_ = 0;  ///< clients_ entries served (not refused at onReady); clients_mutex_
  mg_context* http_ = nullptr;
  std::atomic<bool> stopping_{false};
};

}  // namespace telehand::web
