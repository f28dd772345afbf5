#pragma once
/// A thin RAII layer over the Cyclone DDS C API: participant, topic, writer, reader,
/// waitset, guard condition, and QoS profiles named after their use (docs/design.md "Data over
/// DDS"). dds_write runs on the caller's thread: never call into this from the 1 kHz step.
#include <dds/dds.h>

#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "telehand.h"
#include "telehand/core/error.h"

namespace telehand::dds {

/// Throws DdsError naming `what` if rc is a Cyclone error.
dds_return_t check(dds_return_t rc, const char* what);

/// A Cyclone config as Cyclone's URI: inline XML stays as is, a file becomes
/// file://ABSOLUTE. Throws ConfigError if the file does not exist.
std::string configUri(const std::string& config);

/// Owns one dds_entity_t; deleting it deletes its children too.
class Entity {
 public:
  Entity() = default;
  explicit Entity(dds_entity_t h) : h_(h) {}
  Entity(Entity&& o) noexcept : h_(std::exchange(o.h_, 0)) {}
  Entity& operator=(Entity&& o) noexcept {
    if (this != &o) {
      reset();
      h_ = std::exchange(o.h_, 0);
    }
    return *this;
  }
  Entity(const Entity&) = delete;
  Entity& operator=(const Entity&) = delete;
  ~Entity() { reset(); }
  dds_entity_t handle() const noexcept { return h_; }
  void reset() noexcept;

 private:
  dds_entity_t h_ = 0;
};

/// Owned dds_qos_t with chainable setters.
class Qos {
 public:
  Qos() : q_(dds_create_qos()) {}
  Qos(const Qos& o) : q_(dds_create_qos()) { dds_copy_qos(q_, o.q_); }
  Qos& operator=(const Qos& o) {
    if (this != &o) dds_copy_qos(q_, o.q_);
    return *this;
  }
  ~Qos() { dds_delete_qos(q_); }
  Qos& reliable(std::chrono::milliseconds max_blocking = std::chrono::milliseconds(100));
  Qos& bestEffort();
  Qos& keepLast(int32_t depth);
  Qos& keepAll();
  Qos& volatileDurability();
  Qos& transientLocal();
  Qos& deadline(std::chrono::milliseconds period);
  Qos& partition(const std::string& name);
  /// What a transient-local writer keeps for late joiners. Cyclone uses the durability
  /// service history (default keep-last 1), not the writer's own history depth.
  Qos& lateJoinerHistory(int32_t depth);
  const dds_qos_t* get() const noexcept { return q_; }

  dds_reliability_kind_t reliabilityKind() const;
  dds_durability_kind_t durabilityKind() const;
  std::pair<dds_history_kind_t, int32_t> history() const;

 private:
  dds_qos_t* q_;
};

/// QoS profiles, one per use, as docs/design.md's table states them.
namespace qos {
Qos deviceState();                     ///< best-effort, keep-last 1, volatile, 100 ms deadline
Qos deviceStateReader(int32_t depth);  ///< as deviceState but a deeper reader history
Qos recordChunk();                     ///< reliable, keep-all: the session record's path
Qos jointModel();                      ///< reliable, transient-local, keep-last 1 per session
Qos handState();                       ///< best-effort, keep-last 1
Qos handStateReader(int32_t depth);    ///< as handState but a deeper reader history
Qos sessionCommand();                  ///< reliable, keep-all, volatile
Qos sessionStatus();                   ///< reliable, transient-local, keep-last 1 per session
Qos sessionEvent(
    int32_t depth = 64);             ///< reliable, transient-local, keep-last N (late joiners too)
Qos latencyProbe();                  ///< as deviceState (the probe measures that path)
Qos directForce(int32_t depth = 1);  ///< best-effort, keep-last `depth`, volatile (direct mode)
}  // namespace qos

/// Topic names.
namespace topic {
inline constexpr const char* kDeviceState = "telehand_DeviceState";
inline constexpr const char* kRecordChunk = "telehand_RecordChunk";
inline constexpr const char* kJointModel = "telehand_JointModel";
inline constexpr const char* kHandState = "telehand_HandState";
inline constexpr const char* kSessionCommand = "telehand_SessionCommand";
inline constexpr const char* kSessionStatus = "telehand_SessionStatus";
inline constexpr const char* kSessionEvent = "telehand_SessionEvent";
inline constexpr const char* kLatencyPing = "telehand_LatencyPing";
inline constexpr const char* kLatencyPong = "telehand_LatencyPong";
inline constexpr const char* kDirectForce = "telehand_DirectForce";
}  // namespace topic

/// The participant behind a matched writer: its instance handle in this process and its
/// GUID as hex ("0110a1b2c3d4e5f6:00000007:000001c1"). Under DDS Security the GUID prefix is
/// derived from the participant's authenticated certificate.
struct Sender {
  dds_instance_handle_t participant = 0;
  std::string guid;
};

/// Finds senders from samples' publication handles, remembering up to `capacity` writers
/// (then starting over): one Cyclone lookup per writer, not per sample. Per sample: the last
/// writer's sender at the cost of a comparison (a stream comes from one writer), else one
/// hash lookup; nothing is allocated.
class SenderCache {
 public:
  explicit SenderCache(std::size_t capacity = 4096) : capacity_(capacity) {}
  /// The sender of a sample `reader` took; participant 0 if Cyclone no longer knows the
  /// writer.
  const Sender& of(dds_entity_t reader, dds_instance_handle_t publication) {
    if (publication == last_publication_ && last_ != nullptr) return *last_;
    return lookup(reader, publication);
  }

 private:
  const Sender& lookup(dds_entity_t reader, dds_instance_handle_t publication);

  std::size_t capacity_;
  std::unordered_map<dds_instance_handle_t, Sender> known_;
  Sender unknown_;
  dds_instance_handle_t last_publication_ = 0;
  const Sender* last_ = nullptr;  // known_'s entry for last_publication_
};

/// After a transient-local writer that wrote `instance` unregistered it (on this thread, just
/// before): drops the reference to the instance's key entry that Cyclone DDS 0.10's writer
/// history keeps (fixed upstream in 11.0; a no-op with other versions). Without it every
/// unregistered instance keeps its key entry, about 0.5 kB, for the life of the process.
void releaseUnregistered(dds_instance_handle_t instance) noexcept;

/// Frees the samples Cyclone DDS 0.10 keeps for reuse once they are freed (up to 8,192 of up
/// to 256 bytes per domain, never given back while the domain lives; a no-op with other
/// versions), in the domain this thread last called into. Returns how many it freed. A server
/// calls it when its sessions have ended, so that a burst's samples do not keep its pages.
int releasePooledSamples() noexcept;

/// Which DDS world to join.
struct Options {
  uint32_t domain = 0;
  std::string config;                  ///< Cyclone XML file path or inline XML; empty = default
  std::string partition = "telehand";  ///< isolates sessions, sites and tests
  /// DDS Security (docs/security.md): the directory deploy/pki/make-pki.sh made, and the
  /// identity in it (a subdirectory: server, device, supervisor, engineer...) this
  /// participant authenticates as. Empty `pki`: unsecured.
  std::string pki;
  std::string identity;
  /// The lease this participant announces, seconds (0: Cyclone's, 10 s): how long the others
  /// keep its readers matched after it died. A pool's servers announce a short one, so that a
  /// dead server's readers stop holding up the clients' reliable writers (docs/pool.md).
  double lease_s = 0.0;
};

/// The Cyclone config a participant with these options is created with: `config` as
/// configUri gives it, followed, when `pki` is set, by deploy/cyclonedds/secure.xml, whose
/// variables (TELEHAND_PKI, TELEHAND_IDENTITY, TELEHAND_DDS_SECURITY_LIBDIR) this sets in
/// the environment. Throws ConfigError naming the first missing PKI file, or when Cyclone's
/// security plugins were not found at build time.
std::string participantConfig(const Options& options);

/// What telehand's DDS Security cryptography plugin (common/protocol/crypto/) did in this
/// process: data submessages it encrypted and decrypted itself, received ones it refused
/// (bad tag or form: Cyclone's plugin then refuses them too), and calls it passed on to
/// Cyclone's plugin (key exchange, the first message of each writer, other transforms).
struct CryptoCounts {
  uint64_t encrypted = 0;
  uint64_t decrypted = 0;
  uint64_t refused = 0;
  uint64_t passed_on = 0;
};
/// The counts, or nothing when the plugin is not loaded in this process (no security, or
/// TELEHAND_DDS_CRYPTO=cyclone).
std::optional<CryptoCounts> cryptoCounts();
/// One line for a program's summary: which cryptography ran and what it did.
std::string cryptoSummary(const CryptoCounts& c);

/// A participant with one publisher and one subscriber in the configured partition.
class Participant {
 public:
  /// Throws ConfigError when this process already holds the domain with another config.
  explicit Participant(const Options& options);
  ~Participant();
  Participant(const Participant&) = delete;
  Participant& operator=(const Participant&) = delete;
  dds_entity_t handle() const noexcept { return participant_.handle(); }
  dds_entity_t publisher() const noexcept { return publisher_.handle(); }
  dds_entity_t subscriber() const noexcept { return subscriber_.handle(); }
  const Options& options() const noexcept { return options_; }

 private:
  Options options_;
  Entity domain_;  // only when this participant created the domain from a config
  Entity participant_;
  Entity publisher_;
  Entity subscriber_;
};

template <typename T>
struct TopicTraits;
#define TELEHAND_DDS_TOPIC_TYPE(T)                                          \
  template <>                                                               \
  struct TopicTraits<T> {                                                   \
    static const dds_topic_descriptor_t* descriptor() { return &T##_desc; } \
  }
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_DeviceState);
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_RecordChunk);
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_JointModel);
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_HandState);
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_SessionCommand);
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_SessionStatus);
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_SessionEvent);
TELEHAND_DDS_TOPIC_TYPE(telehand_msg_DirectForce);
#undef TELEHAND_DDS_TOPIC_TYPE

template <typename T>
class Topic {
 public:
  Topic(const Participant& p, const char* name)
      : e_(check(dds_create_topic(p.handle(), TopicTraits<T>::descriptor(), name, nullptr, nullptr),
                 name)) {}
  dds_entity_t handle() const noexcept { return e_.handle(); }

 private:
  Entity e_;
};

/// Every telehand topic on one participant: the one place names meet types.
struct Topics {
  explicit Topics(const Participant& p);
  Topic<telehand_msg_DeviceState> device_state;
  Topic<telehand_msg_RecordChunk> record_chunk;
  Topic<telehand_msg_JointModel> joint_model;
  Topic<telehand_msg_HandState> hand_state;
  Topic<telehand_msg_SessionCommand> session_command;
  Topic<telehand_msg_SessionStatus> session_status;
  Topic<telehand_msg_SessionEvent> session_event;
  Topic<telehand_msg_DeviceState> latency_ping;
  Topic<telehand_msg_DeviceState> latency_pong;
  Topic<telehand_msg_DirectForce> direct_force;
};

/// Frees the nodes of writer histories that Cyclone DDS 0.10 keeps on a process-wide list for
/// reuse (up to 8,192 of about 150 bytes, dds_whc.c, never given back while any writer lives;
/// a no-op with other versions): a writer made for it, in a partition of its own, takes them
/// all into its history and, deleted, frees them (on Cyclone's garbage-collector thread, soon
/// after: their samples then land on the pool releasePooledSamples empties). Returns the
/// samples it wrote. A server calls it when its sessions have ended, before the trim.
int releaseWriterHistoryNodes(const Participant& participant,
                              const Topic<telehand_msg_DirectForce>& topic) noexcept;

template <typename T>
class Writer {
 public:
  Writer(const Participant& p, const Topic<T>& t, const Qos& q)
      : e_(check(dds_create_writer(p.publisher(), t.handle(), q.get(), nullptr), "create writer")) {
  }
  /// Returns Cyclone's return code; callers on hot paths count failures instead of throwing.
  dds_return_t write(const T& sample) noexcept { return dds_write(e_.handle(), &sample); }
  /// Ends the instance `key_sample`'s key names (disposed, then freed by the writer and the
  /// readers): a transient-local writer stops handing it to late joiners. `written`: this
  /// writer is transient-local and wrote the instance, so its history indexed it; Cyclone
  /// DDS 0.10 then keeps the instance's key entry forever (releaseUnregistered), which this
  /// gives back. A wrong `written` frees an entry still in use: pass it only when sure.
  dds_return_t unregister(const T& key_sample, bool written = false) noexcept {
    const dds_instance_handle_t instance =
        written ? dds_lookup_instance(e_.handle(), &key_sample) : DDS_HANDLE_NIL;
    const dds_return_t rc = dds_unregister_instance(e_.handle(), &key_sample);
    if (rc == DDS_RETCODE_OK && instance != DDS_HANDLE_NIL) releaseUnregistered(instance);
    return rc;
  }
  dds_entity_t handle() const noexcept { return e_.handle(); }
  uint32_t matchedReaders() const noexcept {
    dds_publication_matched_status_t st{};
    return dds_get_publication_matched_status(e_.handle(), &st) == DDS_RETCODE_OK ? st.current_count
                                                                                  : 0;
  }

 private:
  Entity e_;
};

template <typename T>
class Reader {
 public:
  Reader(const Participant& p, const Topic<T>& t, const Qos& q)
      : e_(check(dds_create_reader(p.subscriber(), t.handle(), q.get(), nullptr),
                 "create reader")) {
    check(dds_set_status_mask(e_.handle(), DDS_DATA_AVAILABLE_STATUS), "reader status mask");
  }
  dds_entity_t handle() const noexcept { return e_.handle(); }

  /// Takes up to `max` samples (loaned, no copy) and calls fn(const T&, const dds_sample_info_t&)
  /// for each valid one. Returns how many valid samples it saw.
  template <typename Fn>
  std::size_t take(Fn&& fn, std::size_t max = 64) {
    constexpr std::size_t kBatch = 64;
    void* buf[kBatch];
    dds_sample_info_t info[kBatch];
    std::size_t seen = 0;
    while (seen < max) {
      buf[0] = nullptr;
      const dds_return_t n = dds_take(e_.handle(), buf, info, kBatch, kBatch);
      if (n <= 0) break;
      for (dds_return_t i = 0; i < n; ++i) {
        if (info[i].valid_data) {
          fn(*static_cast<const T*>(buf[i]), info[i]);
          ++seen;
        }
      }
      dds_return_loan(e_.handle(), buf, n);
      if (n < static_cast<dds_return_t>(kBatch)) break;
    }
    return seen;
  }

  uint32_t matchedWriters() const noexcept {
    dds_subscription_matched_status_t st{};
    return dds_get_subscription_matched_status(e_.handle(), &st) == DDS_RETCODE_OK
               ? st.current_count
               : 0;
  }

 private:
  Entity e_;
};

/// Calls `fn()` each time samples arrive on a reader, from inside Cyclone: on the receive
/// thread that stored them for a remote writer, on the writing thread for a writer of this
/// process (a DATA_AVAILABLE listener). No thread wakes up between the network and `fn`, which
/// is what a waitset would add. While attached, a waitset on the reader is not triggered by
/// data (the listener consumes the status) and the reader must be taken from `fn` alone.
///
/// `fn` holds up Cyclone's delivery of every other sample while it runs: it must be short,
/// must not throw (std::terminate), allocate per call, lock what another thread holds long,
/// or write to a reliable writer (which may wait for acknowledgements this very thread
/// delivers). Taking and writing best-effort samples is what it is for. Calls for one reader
/// never overlap. Neither copyable nor movable: Cyclone holds its address.
template <typename Fn>
class DataListener {
 public:
  DataListener(dds_entity_t reader, Fn fn) : reader_(reader), fn_(std::move(fn)) {
    dds_listener_t* l = dds_create_listener(this);
    // reset_on_invoke: the status is consumed by the call (no waitset wakes for it).
    dds_lset_data_available_arg(l, &DataListener::invoke, this, true);
    const dds_return_t rc = dds_set_listener(reader_, l);
    dds_delete_listener(l);
    check(rc, "set data-available listener");
  }
  ~DataListener() { detach(); }
  DataListener(const DataListener&) = delete;
  DataListener& operator=(const DataListener&) = delete;

  /// Removes the listener. Cyclone waits for a call under way to return, so `fn`'s effects
  /// are visible to the caller afterwards and `fn` is never called again. Never call this
  /// from `fn` itself (it would wait for itself).
  void detach() noexcept {
    if (reader_ > 0) dds_set_listener(reader_, nullptr);
    reader_ = 0;
  }

 private:
  static void invoke(dds_entity_t, void* self) noexcept { static_cast<DataListener*>(self)->fn_(); }

  dds_entity_t reader_;
  Fn fn_;
};

/// Wakes a waitset from another thread (shutdown, new work).
class GuardCondition {
 public:
  explicit GuardCondition(const Participant& p)
      : e_(check(dds_create_guardcondition(p.handle()), "create guard condition")) {}
  void trigger() noexcept { dds_set_guardcondition(e_.handle(), true); }
  void clear() noexcept { dds_set_guardcondition(e_.handle(), false); }
  dds_entity_t handle() const noexcept { return e_.handle(); }

 private:
  Entity e_;
};

class WaitSet {
 public:
  explicit WaitSet(const Participant& p)
      : e_(check(dds_create_waitset(p.handle()), "create waitset")) {}
  void attach(dds_entity_t entity, dds_attach_t id) {
    check(dds_waitset_attach(e_.handle(), entity, id), "waitset attach");
  }
  /// Waits up to `timeout`; returns the ids of the entities that triggered.
  std::vector<dds_attach_t> wait(std::chrono::nanoseconds timeout);

 private:
  Entity e_;
};

}  // namespace telehand::dds
