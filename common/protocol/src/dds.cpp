#include "telehand/protocol/dds.h"

#include <dds/version.h>
#include <dlfcn.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <string_view>

#include "cyclone_instance_fix.h"

namespace telehand::dds {

dds_return_t check(dds_return_t rc, const char* what) {
  if (rc < 0) {
    throw DdsError(std::string("DDS: ") + what + " failed: " + dds_strretcode(rc));
  }
  return rc;
}

void Entity::reset() noexcept {
  if (h_ > 0) dds_delete(h_);
  h_ = 0;
}

Qos& Qos::reliable(std::chrono::milliseconds max_blocking) {
  dds_qset_reliability(q_, DDS_RELIABILITY_RELIABLE, DDS_MSECS(max_blocking.count()));
  return *this;
}
Qos& Qos::bestEffort() {
  dds_qset_reliability(q_, DDS_RELIABILITY_BEST_EFFORT, 0);
  return *this;
}
Qos& Qos::keepLast(int32_t depth) {
  dds_qset_history(q_, DDS_HISTORY_KEEP_LAST, depth);
  return *this;
}
Qos& Qos::keepAll() {
  dds_qset_history(q_, DDS_HISTORY_KEEP_ALL, DDS_LENGTH_UNLIMITED);
  dds_qset_resource_limits(q_, DDS_LENGTH_UNLIMITED, DDS_LENGTH_UNLIMITED, DDS_LENGTH_UNLIMITED);
  return *this;
}
Qos& Qos::volatileDurability() {
  dds_qset_durability(q_, DDS_DURABILITY_VOLATILE);
  return *this;
}
Qos& Qos::transientLocal() {
  dds_qset_durability(q_, DDS_DURABILITY_TRANSIENT_LOCAL);
  return *this;
}
Qos& Qos::deadline(std::chrono::milliseconds period) {
  dds_qset_deadline(q_, DDS_MSECS(period.count()));
  return *this;
}
Qos& Qos::lateJoinerHistory(int32_t depth) {
  dds_qset_durability_service(q_, 0, DDS_HISTORY_KEEP_LAST, depth, DDS_LENGTH_UNLIMITED,
                              DDS_LENGTH_UNLIMITED, DDS_LENGTH_UNLIMITED);
  return *this;
}
Qos& Qos::partition(const std::string& name) {
  dds_qset_partition1(q_, name.c_str());
  return *this;
}

dds_reliability_kind_t Qos::reliabilityKind() const {
  dds_reliability_kind_t k{};
  dds_duration_t b{};
  if (!dds_qget_reliability(q_, &k, &b)) throw DdsError("QoS has no reliability policy");
  return k;
}
dds_durability_kind_t Qos::durabilityKind() const {
  dds_durability_kind_t k{};
  if (!dds_qget_durability(q_, &k)) throw DdsError("QoS has no durability policy");
  return k;
}
std::pair<dds_history_kind_t, int32_t> Qos::history() const {
  dds_history_kind_t k{};
  int32_t d = 0;
  if (!dds_qget_history(q_, &k, &d)) throw DdsError("QoS has no history policy");
  return {k, d};
}

namespace qos {
Qos deviceState() {
  Qos q;
  q.bestEffort().keepLast(1).volatileDurability().deadline(std::chrono::milliseconds(100));
  return q;
}
Qos deviceStateReader(int32_t depth) {
  Qos q = deviceState();
  q.keepLast(depth);
  return q;
}
Qos recordChunk() {
  Qos q;
  q.reliable(std::chrono::milliseconds(1000)).keepAll().volatileDurability();
  return q;
}
Qos jointModel() {
  Qos q;
  q.reliable().keepLast(1).transientLocal();
  return q;
}
Qos directForce(int32_t depth) {
  Qos q;
  q.bestEffort().keepLast(depth).volatileDurability();
  return q;
}
Qos handState() {
  Qos q;
  q.bestEffort().keepLast(1).volatileDurability();
  return q;
}
Qos sessionCommand() {
  Qos q;
  q.reliable().keepAll().volatileDurability();
  return q;
}
Qos sessionStatus() {
  Qos q;
  q.reliable().keepLast(1).transientLocal();
  return q;
}
Qos sessionEvent(int32_t depth) {
  Qos q;
  q.reliable().keepLast(depth).transientLocal().lateJoinerHistory(depth);
  return q;
}
Qos handStateReader(int32_t depth) {
  Qos q = handState();
  q.keepLast(depth);
  return q;
}
Qos latencyProbe() { return deviceState(); }
}  // namespace qos

std::string configUri(const std::string& config) {
  if (config.empty() || config.front() == '<') return config;
  std::error_code ec;
  const auto path = std::filesystem::absolute(config, ec);
  if (ec || !std::filesystem::is_regular_file(path)) {
    throw ConfigError("DDS config file '" + config + "' does not exist or is not a file");
  }
  return "file://" + path.string();
}

const Sender& SenderCache::lookup(dds_entity_t reader, dds_instance_handle_t publication) {
  if (auto it = known_.find(publication); it != known_.end()) {
    last_publication_ = publication;
    last_ = &it->second;
    return it->second;
  }
  dds_builtintopic_endpoint_t* ep = dds_get_matched_publication_data(reader, publication);
  if (!ep) return unknown_;
  Sender s;
  s.participant = ep->participant_instance_handle;
  char hex[40];
  const uint8_t* g = ep->participant_key.v;
  std::snprintf(hex, sizeof hex,
                "%02x%02x%02x%02x%02x%02x%02x%02x:%02x%02x%02x%02x:%02x%02x%02x%02x", g[0], g[1],
                g[2], g[3], g[4], g[5], g[6], g[7], g[8], g[9], g[10], g[11], g[12], g[13], g[14],
                g[15]);
  s.guid = hex;
  dds_builtintopic_free_endpoint(ep);
  if (known_.size() >= capacity_) known_.clear();
  last_publication_ = publication;
  last_ = &known_.emplace(publication, std::move(s)).first->second;
  return *last_;
}

void releaseUnregistered(dds_instance_handle_t instance) noexcept {
  telehand_dds_release_unregistered(instance);
}

int releasePooledSamples() noexcept { return telehand_dds_release_pooled_samples(); }

int releaseWriterHistoryNodes(const Participant& participant,
                              const Topic<telehand_msg_DirectForce>& topic) noexcept {
#if DDS_VERSION_MAJOR == 0 && DDS_VERSION_MINOR == 10
  // The list (dds_whc.c, whc_node_freelist, MAX_FREELIST_SIZE) is static to the library: it
  // is reached through a writer. Transient-local with no reader, its history keeps every
  // sample up to its depth, each in a node taken from the list (or new once it is empty);
  // deleting the writer frees its history's nodes to the heap, not to the list. The
  // partition is this process's own, so no reader anywhere matches the writer.
  constexpr int32_t kNodes = 8192;
  dds_qos_t* pq = dds_create_qos();
  char name[64];
  std::snprintf(name, sizeof name, "telehand-whc-release-%d", static_cast<int>(getpid()));
  const char* parts[] = {name};
  dds_qset_partition(pq, 1, parts);
  const dds_entity_t pub = dds_create_publisher(participant.handle(), pq, nullptr);
  dds_delete_qos(pq);
  if (pub < 0) return 0;
  dds_qos_t* wq = dds_create_qos();
  dds_qset_reliability(wq, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_durability(wq, DDS_DURABILITY_TRANSIENT_LOCAL);
  dds_qset_history(wq, DDS_HISTORY_KEEP_LAST, kNodes);
  dds_qset_durability_service(wq, 0, DDS_HISTORY_KEEP_LAST, kNodes, DDS_LENGTH_UNLIMITED,
                              DDS_LENGTH_UNLIMITED, DDS_LENGTH_UNLIMITED);
  const dds_entity_t wr = dds_create_writer(pub, topic.handle(), wq, nullptr);
  dds_delete_qos(wq);
  int n = 0;
  if (wr >= 0) {
    telehand_msg_DirectForce sample{};
    for (; n < kNodes; ++n) {
      sample.device_seq = static_cast<uint64_t>(n);
      if (dds_write(wr, &sample) < 0) break;
    }
  }
  dds_delete(pub);
  return n;
#else
  (void)participant;
  (void)topic;
  return 0;
#endif
}

std::string participantConfig(const Options& options) {
  std::string uri = configUri(options.config);
  if (options.lease_s > 0.0) {
    char lease[160];
    std::snprintf(lease, sizeof lease,
                  "<CycloneDDS><Domain Id=\"any\"><Discovery><LeaseDuration>%.3f s</LeaseDuration>"
                  "</Discovery></Domain></CycloneDDS>",
                  options.lease_s);
    uri = uri.empty() ? std::string(lease) : uri + "," + lease;
  }
  if (options.pki.empty()) return uri;
#ifndef TELEHAND_DDS_SECURITY_LIBDIR
  throw ConfigError(
      "DDS Security was asked for (--pki) but Cyclone's security plugins "
      "(libdds_security_auth.so) were not found when telehand was built");
#else
  namespace fs = std::filesystem;
  if (options.identity.empty()) throw ConfigError("DDS Security: --pki needs an --identity");
  const fs::path pki = fs::absolute(options.pki);
  const fs::path id = pki / options.identity;
  for (const fs::path& f : {pki / "ca" / "ca.pem", pki / "governance.p7s", id / "identity.pem",
                            id / "identity.key", id / "permissions.p7s"}) {
    std::error_code ec;
    if (!fs::is_regular_file(f, ec)) {
      throw ConfigError("DDS Security: '" + f.string() + "' is missing (identity '" +
                        options.identity + "' in PKI '" + options.pki +
                        "'; deploy/pki/make-pki.sh makes them)");
    }
  }
  // Read by Cyclone when it creates the domain; programs create their participants before
  // starting threads.
  ::setenv("TELEHAND_PKI", pki.c_str(), 1);
  ::setenv("TELEHAND_IDENTITY", options.identity.c_str(), 1);
  ::setenv("TELEHAND_DDS_SECURITY_LIBDIR", TELEHAND_DDS_SECURITY_LIBDIR, 1);
  // The cryptography plugin: telehand's (docs/security.md "Cost") unless the environment asks
  // for Cyclone's own (TELEHAND_DDS_CRYPTO=cyclone; the two read each other).
  const char* crypto = std::getenv("TELEHAND_DDS_CRYPTO");
  const std::string_view choice = crypto == nullptr ? "telehand" : crypto;
  if (choice == "cyclone") {
    ::setenv("TELEHAND_DDS_CRYPTO_PLUGIN",
             TELEHAND_DDS_SECURITY_LIBDIR "/libdds_security_crypto.so", 1);
    ::setenv("TELEHAND_DDS_CRYPTO_INIT", "init_crypto", 1);
    ::setenv("TELEHAND_DDS_CRYPTO_FINALIZE", "finalize_crypto", 1);
  } else if (choice == "telehand") {
    ::setenv("TELEHAND_DDS_CRYPTO_PLUGIN", TELEHAND_DDS_CRYPTO_PLUGIN, 1);
    ::setenv("TELEHAND_DDS_CRYPTO_INIT", "telehand_init_crypto", 1);
    ::setenv("TELEHAND_DDS_CRYPTO_FINALIZE", "telehand_finalize_crypto", 1);
  } else {
    throw ConfigError("TELEHAND_DDS_CRYPTO is '" + std::string(choice) +
                      "'; it must be 'telehand' (the default) or 'cyclone'");
  }
  const std::string secure = configUri(TELEHAND_SECURE_XML);
  return uri.empty() ? secure : uri + "," + secure;
#endif
}

std::optional<CryptoCounts> cryptoCounts() {
#ifdef TELEHAND_DDS_CRYPTO_PLUGIN
  // Only when Cyclone loaded it: RTLD_NOLOAD does not load it here.
  void* lib = ::dlopen(TELEHAND_DDS_CRYPTO_PLUGIN, RTLD_NOW | RTLD_NOLOAD);
  if (lib == nullptr) return std::nullopt;
  using Fn = void (*)(uint64_t*, uint64_t*, uint64_t*, uint64_t*);
  const auto fn = reinterpret_cast<Fn>(::dlsym(lib, "telehand_crypto_counts"));
  std::optional<CryptoCounts> out;
  if (fn != nullptr) {
    CryptoCounts c;
    fn(&c.encrypted, &c.decrypted, &c.refused, &c.passed_on);
    out = c;
  }
  ::dlclose(lib);
  return out;
#else
  return std::nullopt;
#endif
}

std::string cryptoSummary(const CryptoCounts& c) {
  char line[256];
  std::snprintf(
      line, sizeof line,
      "telehand's cryptography: %llu data submessages encrypted, %llu decrypted, "
      "%llu refused, %llu calls passed to Cyclone's",
      static_cast<unsigned long long>(c.encrypted), static_cast<unsigned long long>(c.decrypted),
      static_cast<unsigned long long>(c.refused), static_cast<unsigned long long>(c.passed_on));
  return line;
}

namespace {
std::mutex& domainsMutex() {
  static std::mutex m;
  return m;
}
/// The config of each domain a Participant of this process created (and still holds).
std::map<uint32_t, std::string>& domainConfigs() {
  static std::map<uint32_t, std::string> configs;
  return configs;
}
}  // namespace

Participant::~Participant() {
  subscriber_.reset();
  publisher_.reset();
  participant_.reset();
  if (domain_.handle() > 0) {
    const std::lock_guard lock(domainsMutex());
    domain_.reset();
    domainConfigs().erase(options_.domain);
  }
}

Participant::Participant(const Options& options) : options_(options) {
  if (options.domain > 230) {
    throw ConfigError("DDS domain " + std::to_string(options.domain) + " is out of range 0..230");
  }
  const std::string config = participantConfig(options);
  // A domain is created once per process, with the first config it is asked for; a second
  // participant asking for another config (another identity) would silently get the first.
  const std::lock_guard lock(domainsMutex());
  auto& configs = domainConfigs();
  if (const auto it = configs.find(options.domain);
      !config.empty() && it != configs.end() && it->second != config) {
    throw ConfigError("DDS domain " + std::to_string(options.domain) +
                      " is already in use in this process with another config or identity");
  }
  if (!config.empty()) {
    const dds_entity_t d = dds_create_domain(options.domain, config.c_str());
    if (d > 0) {
      domain_ = Entity(d);
      configs[options.domain] = config;
    } else if (d != DDS_RETCODE_PRECONDITION_NOT_MET) {  // already created in this process
      check(d, ("create domain from '" + options.config + "'" +
                (options.pki.empty() ? "" : " with identity '" + options.identity + "'"))
                   .c_str());
    }
  }
  participant_ = Entity(check(dds_create_participant(options.domain, nullptr, nullptr),
                              "create participant (check the DDS config and network)"));
  Qos q;
  q.partition(options.partition);
  publisher_ = Entity(
      check(dds_create_publisher(participant_.handle(), q.get(), nullptr), "create publisher"));
  subscriber_ = Entity(
      check(dds_create_subscriber(participant_.handle(), q.get(), nullptr), "create subscriber"));
}

Topics::Topics(const Participant& p)
    : device_state(p, topic::kDeviceState),
      record_chunk(p, topic::kRecordChunk),
      joint_model(p, topic::kJointModel),
      hand_state(p, topic::kHandState),
      session_command(p, topic::kSessionCommand),
      session_status(p, topic::kSessionStatus),
      session_event(p, topic::kSessionEvent),
      latency_ping(p, topic::kLatencyPing),
      latency_pong(p, topic::kLatencyPong),
      direct_force(p, topic::kDirectForce) {}

std::vector<dds_attach_t> WaitSet::wait(std::chrono::nanoseconds timeout) {
  dds_attach_t xs[16];
  const dds_return_t n = dds_waitset_wait(e_.handle(), xs, 16, timeout.count());
  check(n, "waitset wait");
  return {xs, xs + n};
}

}  // namespace telehand::dds
