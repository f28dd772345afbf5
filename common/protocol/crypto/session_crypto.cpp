// telehand's DDS Security cryptography plugin (docs/security.md "Cost"): Cyclone's own
// (libdds_security_crypto.so, Debian's) does everything, the key exchange included; this
// plugin takes over only the AES-GCM transform of the data submessages of writers whose
// submessages are encrypted without receiver-specific MACs, which Cyclone 0.10.2's does in a
// way that costs more than the cipher: a new OpenSSL cipher context (with its provider
// look-up) for every message, and on receipt the session key derived again (HMAC-SHA256) for
// every message. Here each writer keeps its cipher context and its session key, and each
// remote writer the last session key it derived, so a message costs one AES-GCM pass.
//
// The wire format is the one DDS Security 1.1 (section 9.5.3.3) defines and Cyclone's plugin
// writes and reads: SEC_PREFIX (transformation kind and key id, session id, IV suffix),
// SEC_BODY (the encrypted submessage), SEC_POSTFIX (the GCM tag, no receiver-specific MAC).
// The keys are the ones Cyclone's plugin made and exchanged (its writers' crypto tokens);
// the session key is HMAC-SHA256(master key, "SessionKey" | master salt | session id), the
// IV the session id and a counter. So a participant with this plugin and one with Cyclone's
// read each other (SecurityTest.TelehandAndCycloneCryptographyReadEachOther).
//
// Anything else (the volatile key-exchange endpoints, signed-only or origin-authenticated
// submessages, payload and RTPS-message protection, data readers' submessages) and any
// message this plugin cannot encode or decode (a bad tag, an unknown key) goes to Cyclone's
// plugin, which then also writes the error.
#include <dlfcn.h>
#include <openssl/evp.h>
#include <openssl/rand.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <vector>

// Not dds_security_api.h: its ddsi_domaingv.h does not compile as C++, and the plugin needs
// only the cryptography interface and the plugin entry points' types.
#include "dds/security/dds_security_api_cryptography.h"
#include "dds/security/dds_security_api_defs.h"
#include "secured_submessage.h"

extern "C" {
struct ddsi_domaingv;
typedef int (*plugin_init)(const char* argument, void** context, struct ddsi_domaingv* gv);
typedef int (*plugin_finalize)(void* context);
}

namespace {

using namespace telehand::dds::crypto;

/// A new session (key) after this many messages; the IV's counter never repeats within one.
constexpr uint64_t kMessagesPerSession = uint64_t{1} << 32;

/// The key material of a writer's crypto token (its first binary property).
bool tokenKeyMaterial(const DDS_Security_DataHolder& token, KeyMaterial& out) {
  if (token.binary_properties._length < 1 || token.binary_properties._buffer == nullptr) {
    return false;
  }
  const DDS_Security_BinaryProperty_t& prop = token.binary_properties._buffer[0];
  return prop.name != nullptr && std::strcmp(prop.name, "dds.cryp.keymat") == 0 &&
         parseKeyMaterial(prop.value._buffer, prop.value._length, out);
}

struct CipherCtx {
  EVP_CIPHER_CTX* ctx = EVP_CIPHER_CTX_new();
  CipherCtx() = default;
  CipherCtx(const CipherCtx&) = delete;
  CipherCtx& operator=(const CipherCtx&) = delete;
  ~CipherCtx() { EVP_CIPHER_CTX_free(ctx); }
};

/// A local writer's transform: its key (learnt from its tokens), its session, its context.
struct LocalWriter {
  std::mutex mu;
  bool eligible = false;  ///< encrypted submessages, no receiver-specific MACs
  bool disabled = false;  ///< its tokens disagreed: Cyclone's plugin keeps it
  std::vector<KeyMaterial> tokens;
  bool active = false;
  KeyMaterial km;
  uint32_t session_id = 0;
  uint32_t cyclone_session_id = 0;  ///< the session Cyclone's plugin used: never this one's
  uint64_t iv_suffix = 0;
  uint64_t session_messages = 0;
  CipherCtx cipher;
};

/// A remote writer as one local reader sees it: the keys it sent, the last session key.
struct RemoteWriter {
  std::mutex mu;
  std::vector<KeyMaterial> keys;
  bool have_session = false;
  uint32_t session_key_id = 0;
  uint32_t session_id = 0;
  CipherCtx cipher;
};

struct Plugin;
struct BaseBox {
  dds_security_cryptography api;  // what Cyclone holds
  Plugin* self;
};
struct FactoryBox {
  dds_security_crypto_key_factory api;
  Plugin* self;
};
struct ExchangeBox {
  dds_security_crypto_key_exchange api;
  Plugin* self;
};
struct TransformBox {
  dds_security_crypto_transform api;
  Plugin* self;
};

struct Plugin {
  BaseBox base{};  // what Cyclone holds; its members point at the boxes below
  FactoryBox factory{};
  ExchangeBox exchange{};
  TransformBox transform{};
  void* library = nullptr;
  plugin_finalize inner_finalize = nullptr;
  void* inner_context = nullptr;
  dds_security_cryptography* inner = nullptr;
  const EVP_CIPHER* aes128 = nullptr;
  const EVP_CIPHER* aes256 = nullptr;

  std::shared_mutex map_mu;
  std::unordered_map<int64_t, bool> reader_encrypted;  // local reader -> submessages encrypted
  std::unordered_map<int64_t, std::shared_ptr<LocalWriter>> local_writers;
  std::unordered_map<int64_t, std::shared_ptr<RemoteWriter>> remote_writers;

  // What this process's plugins did, over all of them (a participant made again makes the
  // domain, and so the plugin, again).
  static inline std::atomic<uint64_t> fast_encodes{0};
  static inline std::atomic<uint64_t> fast_decodes{0};
  static inline std::atomic<uint64_t> refused{0};
  static inline std::atomic<uint64_t> passed_on{0};

  const EVP_CIPHER* cipherFor(uint32_t kind) const { return kind == kAes256Gcm ? aes256 : aes128; }
  template <class T>
  std::shared_ptr<T> find(std::unordered_map<int64_t, std::shared_ptr<T>>& map, int64_t h) {
    const std::shared_lock lock(map_mu);
    const auto it = map.find(h);
    return it == map.end() ? nullptr : it->second;
  }
  bool readerEncrypted(int64_t h) {
    const std::shared_lock lock(map_mu);
    const auto it = reader_encrypted.find(h);
    return it != reader_encrypted.end() && it->second;
  }
};

Plugin* self(dds_security_crypto_key_factory* i) { return reinterpret_cast<FactoryBox*>(i)->self; }
Plugin* self(dds_security_crypto_key_exchange* i) {
  return reinterpret_cast<ExchangeBox*>(i)->self;
}
Plugin* self(dds_security_crypto_transform* i) { return reinterpret_cast<TransformBox*>(i)->self; }

bool endpointEncrypted(const DDS_Security_EndpointSecurityAttributes* a) {
  return a != nullptr && a->is_submessage_protected &&
         (a->plugin_endpoint_attributes &
          DDS_SECURITY_PLUGIN_ENDPOINT_ATTRIBUTES_FLAG_IS_SUBMESSAGE_ENCRYPTED) != 0 &&
         (a->plugin_endpoint_attributes &
          DDS_SECURITY_PLUGIN_ENDPOINT_ATTRIBUTES_FLAG_IS_SUBMESSAGE_ORIGIN_AUTHENTICATED) == 0;
}

// ---- key factory: note which endpoints qualify, forget them when they go ----

DDS_Security_DatawriterCryptoHandle registerLocalWriter(
    dds_security_crypto_key_factory* instance, const DDS_Security_ParticipantCryptoHandle pp,
    const DDS_Security_PropertySeq* props, const DDS_Security_EndpointSecurityAttributes* attr,
    DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  const auto h = p->inner->crypto_key_factory->register_local_datawriter(
      p->inner->crypto_key_factory, pp, props, attr, ex);
  if (h != DDS_SECURITY_HANDLE_NIL) {
    auto w = std::make_shared<LocalWriter>();
    w->eligible = endpointEncrypted(attr) && w->cipher.ctx != nullptr;
    const std::unique_lock lock(p->map_mu);
    p->local_writers[h] = std::move(w);  // a handle reused after an unregister starts afresh
  }
  return h;
}

DDS_Security_DatareaderCryptoHandle registerLocalReader(
    dds_security_crypto_key_factory* instance, const DDS_Security_ParticipantCryptoHandle pp,
    const DDS_Security_PropertySeq* props, const DDS_Security_EndpointSecurityAttributes* attr,
    DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  const auto h = p->inner->crypto_key_factory->register_local_datareader(
      p->inner->crypto_key_factory, pp, props, attr, ex);
  if (h != DDS_SECURITY_HANDLE_NIL) {
    const std::unique_lock lock(p->map_mu);
    p->reader_encrypted[h] = endpointEncrypted(attr);
  }
  return h;
}

DDS_Security_DatawriterCryptoHandle registerRemoteWriter(
    dds_security_crypto_key_factory* instance, const DDS_Security_DatareaderCryptoHandle reader,
    const DDS_Security_ParticipantCryptoHandle remote_pp, const DDS_Security_SharedSecretHandle s,
    DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  const auto h = p->inner->crypto_key_factory->register_matched_remote_datawriter(
      p->inner->crypto_key_factory, reader, remote_pp, s, ex);
  if (h != DDS_SECURITY_HANDLE_NIL) {
    const std::unique_lock lock(p->map_mu);
    p->remote_writers.erase(h);
  }
  return h;
}

DDS_Security_boolean unregisterWriter(dds_security_crypto_key_factory* instance,
                                      const DDS_Security_DatawriterCryptoHandle h,
                                      DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  {
    const std::unique_lock lock(p->map_mu);
    p->local_writers.erase(h);
    p->remote_writers.erase(h);
  }
  return p->inner->crypto_key_factory->unregister_datawriter(p->inner->crypto_key_factory, h, ex);
}

DDS_Security_boolean unregisterReader(dds_security_crypto_key_factory* instance,
                                      const DDS_Security_DatareaderCryptoHandle h,
                                      DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  {
    const std::unique_lock lock(p->map_mu);
    p->reader_encrypted.erase(h);
  }
  return p->inner->crypto_key_factory->unregister_datareader(p->inner->crypto_key_factory, h, ex);
}

// ---- key exchange: learn the writers' keys from their tokens ----

DDS_Security_boolean createLocalWriterTokens(dds_security_crypto_key_exchange* instance,
                                             DDS_Security_DatawriterCryptoTokenSeq* tokens,
                                             const DDS_Security_DatawriterCryptoHandle writer,
                                             const DDS_Security_DatareaderCryptoHandle reader,
                                             DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  const DDS_Security_boolean ok =
      p->inner->crypto_key_exchange->create_local_datawriter_crypto_tokens(
          p->inner->crypto_key_exchange, tokens, writer, reader, ex);
  if (!ok || tokens == nullptr) return ok;
  if (const auto w = p->find(p->local_writers, writer)) {
    const std::lock_guard lock(w->mu);
    for (uint32_t i = 0; i < tokens->_length; ++i) {
      KeyMaterial km;
      if (!tokenKeyMaterial(tokens->_buffer[i], km)) continue;
      bool known = false;
      for (const KeyMaterial& t : w->tokens) {
        if (t.sender_key_id == km.sender_key_id) {
          known = true;
          if (!sameKey(t, km)) w->disabled = true;  // a key changed under the same id
        }
      }
      if (!known) w->tokens.push_back(km);
      // A reader matched later must get the key this writer encrypts with.
      if (w->active && km.sender_key_id == w->km.sender_key_id && !sameKey(km, w->km)) {
        w->disabled = true;
      }
    }
    if (w->disabled) w->active = false;
  }
  return ok;
}

DDS_Security_boolean setRemoteWriterTokens(dds_security_crypto_key_exchange* instance,
                                           const DDS_Security_DatareaderCryptoHandle reader,
                                           const DDS_Security_DatawriterCryptoHandle writer,
                                           const DDS_Security_DatawriterCryptoTokenSeq* tokens,
                                           DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  const DDS_Security_boolean ok =
      p->inner->crypto_key_exchange->set_remote_datawriter_crypto_tokens(
          p->inner->crypto_key_exchange, reader, writer, tokens, ex);
  if (!ok || tokens == nullptr) return ok;
  auto rw = std::make_shared<RemoteWriter>();
  for (uint32_t i = 0; i < tokens->_length && i < 2; ++i) {
    KeyMaterial km;
    if (tokenKeyMaterial(tokens->_buffer[i], km)) rw->keys.push_back(km);
  }
  const std::unique_lock lock(p->map_mu);
  if (rw->keys.empty() || rw->cipher.ctx == nullptr) {
    p->remote_writers.erase(writer);
  } else {
    p->remote_writers[writer] = std::move(rw);
  }
  return ok;
}

// ---- transform ----

/// Learns which of the writer's keys Cyclone's plugin encrypts with from the first message it
/// encoded, and starts this writer's own session with it (a session id other than that one).
void activate(Plugin* p, LocalWriter& w, const DDS_Security_OctetSeq& encoded) {
  Secured theirs;
  if (!parseSecured(encoded._buffer, encoded._length, theirs)) return;
  const uint32_t kind = theirs.kind;
  const uint32_t key_id = theirs.key_id;
  const uint32_t their_session = theirs.session_id;
  for (const KeyMaterial& km : w.tokens) {
    if (km.sender_key_id != key_id || km.kind != kind) continue;
    uint32_t sid = 0;
    uint64_t iv = 0;
    do {
      if (RAND_bytes(reinterpret_cast<unsigned char*>(&sid), sizeof sid) != 1 ||
          RAND_bytes(reinterpret_cast<unsigned char*>(&iv), sizeof iv) != 1) {
        return;
      }
    } while (sid == their_session);
    std::array<uint8_t, 32> key{};
    const bool keyed =
        sessionKey(km, sid, key) &&
        EVP_EncryptInit_ex(w.cipher.ctx, p->cipherFor(kind), nullptr, key.data(), nullptr) == 1;
    OPENSSL_cleanse(key.data(), key.size());
    if (!keyed) return;
    w.km = km;
    w.session_id = sid;
    w.cyclone_session_id = their_session;
    w.iv_suffix = iv;
    w.session_messages = 0;
    w.active = true;
    return;
  }
}

bool newSession(Plugin* p, LocalWriter& w) {
  std::array<uint8_t, 32> key{};
  if (++w.session_id == w.cyclone_session_id) ++w.session_id;
  const bool keyed =
      sessionKey(w.km, w.session_id, key) &&
      EVP_EncryptInit_ex(w.cipher.ctx, p->cipherFor(w.km.kind), nullptr, key.data(), nullptr) == 1;
  OPENSSL_cleanse(key.data(), key.size());
  w.session_messages = 0;
  return keyed;
}

/// The secured form (secured_submessage.h) of one plain submessage, with the writer's session.
bool encodeFast(Plugin* p, LocalWriter& w, const DDS_Security_OctetSeq& plain,
                DDS_Security_OctetSeq& out) {
  if (plain._length == 0 || plain._length % 4 != 0 || plain._length > 0xffff - 8) return false;
  if (w.session_messages >= kMessagesPerSession && !newSession(p, w)) return false;
  const size_t n = plain._length;
  const size_t total = securedSize(n);
  auto* buf = static_cast<uint8_t*>(std::malloc(total));
  if (buf == nullptr) return false;
  ++w.iv_suffix;
  ++w.session_messages;
  const Frame f = writeFrame(buf, n, w.km.kind, w.km.sender_key_id, w.session_id, w.iv_suffix);
  const bool ok = seal(w.cipher.ctx, plain._buffer, n, f);
  if (!ok) {
    std::free(buf);
    return false;
  }
  out._buffer = buf;
  out._length = static_cast<uint32_t>(total);
  out._maximum = static_cast<uint32_t>(total);
  return true;
}

DDS_Security_boolean encodeWriterSubmessage(dds_security_crypto_transform* instance,
                                            DDS_Security_OctetSeq* encoded,
                                            const DDS_Security_OctetSeq* plain,
                                            const DDS_Security_DatawriterCryptoHandle writer,
                                            const DDS_Security_DatareaderCryptoHandleSeq* readers,
                                            DDS_Security_long* index,
                                            DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  auto* inner = p->inner->crypto_transform;
  std::shared_ptr<LocalWriter> w;
  if (index != nullptr && *index == 0 && plain != nullptr && encoded != nullptr &&
      readers != nullptr && readers->_length > 0) {
    w = p->find(p->local_writers, writer);
  }
  if (w == nullptr || !w->eligible) {
    p->passed_on.fetch_add(1, std::memory_order_relaxed);
    return inner->encode_datawriter_submessage(inner, encoded, plain, writer, readers, index, ex);
  }
  const std::lock_guard lock(w->mu);
  if (w->active && !w->disabled && encodeFast(p, *w, *plain, *encoded)) {
    *index = static_cast<DDS_Security_long>(readers->_length);
    p->fast_encodes.fetch_add(1, std::memory_order_relaxed);
    return true;
  }
  p->passed_on.fetch_add(1, std::memory_order_relaxed);
  const DDS_Security_boolean ok =
      inner->encode_datawriter_submessage(inner, encoded, plain, writer, readers, index, ex);
  // Cyclone's plugin wrote this one: its prefix names the key; take over from the next.
  if (ok && !w->active && !w->disabled &&
      *index == static_cast<DDS_Security_long>(readers->_length)) {
    activate(p, *w, *encoded);
  }
  return ok;
}

bool decodeFast(Plugin* p, RemoteWriter& rw, const DDS_Security_OctetSeq& encoded,
                DDS_Security_OctetSeq& plain) {
  Secured m;
  if (!parseSecured(encoded._buffer, encoded._length, m)) return false;
  const KeyMaterial* km = nullptr;
  for (const KeyMaterial& k : rw.keys) {
    if (k.sender_key_id == m.key_id && k.kind == m.kind) km = &k;
  }
  if (km == nullptr) return false;
  if (!rw.have_session || rw.session_id != m.session_id || rw.session_key_id != m.key_id) {
    std::array<uint8_t, 32> key{};
    rw.have_session =
        sessionKey(*km, m.session_id, key) &&
        EVP_DecryptInit_ex(rw.cipher.ctx, p->cipherFor(m.kind), nullptr, key.data(), nullptr) == 1;
    OPENSSL_cleanse(key.data(), key.size());
    if (!rw.have_session) return false;
    rw.session_id = m.session_id;
    rw.session_key_id = m.key_id;
  }
  auto* out = static_cast<uint8_t*>(std::malloc(m.n));
  if (out == nullptr) return false;
  const bool ok = unseal(rw.cipher.ctx, m, out);
  if (!ok) {
    std::free(out);
    return false;
  }
  plain._buffer = out;
  plain._length = static_cast<uint32_t>(m.n);
  plain._maximum = static_cast<uint32_t>(m.n);
  return true;
}

DDS_Security_boolean decodeWriterSubmessage(dds_security_crypto_transform* instance,
                                            DDS_Security_OctetSeq* plain,
                                            const DDS_Security_OctetSeq* encoded,
                                            const DDS_Security_DatareaderCryptoHandle reader,
                                            const DDS_Security_DatawriterCryptoHandle writer,
                                            DDS_Security_SecurityException* ex) {
  Plugin* p = self(instance);
  auto* inner = p->inner->crypto_transform;
  if (plain != nullptr && encoded != nullptr && p->readerEncrypted(reader)) {
    if (const auto rw = p->find(p->remote_writers, writer)) {
      const std::lock_guard lock(rw->mu);
      if (decodeFast(p, *rw, *encoded, *plain)) {
        p->fast_decodes.fetch_add(1, std::memory_order_relaxed);
        return true;
      }
      p->refused.fetch_add(1, std::memory_order_relaxed);
    }
  }
  p->passed_on.fetch_add(1, std::memory_order_relaxed);
  return inner->decode_datawriter_submessage(inner, plain, encoded, reader, writer, ex);
}

// Everything else is Cyclone's plugin's, called on its own instance.
#define TELEHAND_FORWARD(iface, member)                                                 \
  [](auto* instance, auto... args) {                                                    \
    return self(instance)->inner->iface->member(self(instance)->inner->iface, args...); \
  }

}  // namespace

extern "C" {

/// What this process's plugins did (all of them, made again with the domain or not): data
/// submessages encrypted and decrypted here, received ones refused (Cyclone's plugin, called
/// next, refuses them too), and calls passed on to Cyclone's plugin. Read by
/// telehand::dds::cryptoCounts.
__attribute__((visibility("default"))) void telehand_crypto_counts(uint64_t* encrypted,
                                                                   uint64_t* decrypted,
                                                                   uint64_t* refused,
                                                                   uint64_t* passed_on) {
  *encrypted = Plugin::fast_encodes.load();
  *decrypted = Plugin::fast_decodes.load();
  *refused = Plugin::refused.load();
  *passed_on = Plugin::passed_on.load();
}

__attribute__((visibility("default"))) int telehand_init_crypto(const char* argument,
                                                                void** context,
                                                                struct ddsi_domaingv* gv) {
  *context = nullptr;
  const char* dir = std::getenv("TELEHAND_DDS_SECURITY_LIBDIR");
  const std::string path =
      std::string(dir ? dir : TELEHAND_DDS_SECURITY_LIBDIR_DEFAULT) + "/libdds_security_crypto.so";
  void* lib = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (lib == nullptr) return DDS_SECURITY_FAILED;
  auto init = reinterpret_cast<plugin_init>(dlsym(lib, "init_crypto"));
  auto fini = reinterpret_cast<plugin_finalize>(dlsym(lib, "finalize_crypto"));
  void* inner_context = nullptr;
  if (init == nullptr || fini == nullptr ||
      init(argument, &inner_context, gv) != DDS_SECURITY_SUCCESS || inner_context == nullptr) {
    dlclose(lib);
    return DDS_SECURITY_FAILED;
  }
  auto* p = new Plugin;
  p->library = lib;
  p->inner_finalize = fini;
  p->inner_context = inner_context;
  p->inner = static_cast<dds_security_cryptography*>(inner_context);
  p->aes128 = EVP_CIPHER_fetch(nullptr, "AES-128-GCM", nullptr);
  p->aes256 = EVP_CIPHER_fetch(nullptr, "AES-256-GCM", nullptr);

  p->factory.self = p;
  p->factory.api = *p->inner->crypto_key_factory;
  p->factory.api.register_local_participant =
      TELEHAND_FORWARD(crypto_key_factory, register_local_participant);
  p->factory.api.register_matched_remote_participant =
      TELEHAND_FORWARD(crypto_key_factory, register_matched_remote_participant);
  p->factory.api.register_local_datawriter = registerLocalWriter;
  p->factory.api.register_matched_remote_datareader =
      TELEHAND_FORWARD(crypto_key_factory, register_matched_remote_datareader);
  p->factory.api.register_local_datareader = registerLocalReader;
  p->factory.api.register_matched_remote_datawriter = registerRemoteWriter;
  p->factory.api.unregister_participant =
      TELEHAND_FORWARD(crypto_key_factory, unregister_participant);
  p->factory.api.unregister_datawriter = unregisterWriter;
  p->factory.api.unregister_datareader = unregisterReader;

  p->exchange.self = p;
  p->exchange.api.create_local_participant_crypto_tokens =
      TELEHAND_FORWARD(crypto_key_exchange, create_local_participant_crypto_tokens);
  p->exchange.api.set_remote_participant_crypto_tokens =
      TELEHAND_FORWARD(crypto_key_exchange, set_remote_participant_crypto_tokens);
  p->exchange.api.create_local_datawriter_crypto_tokens = createLocalWriterTokens;
  p->exchange.api.set_remote_datawriter_crypto_tokens = setRemoteWriterTokens;
  p->exchange.api.create_local_datareader_crypto_tokens =
      TELEHAND_FORWARD(crypto_key_exchange, create_local_datareader_crypto_tokens);
  p->exchange.api.set_remote_datareader_crypto_tokens =
      TELEHAND_FORWARD(crypto_key_exchange, set_remote_datareader_crypto_tokens);
  p->exchange.api.return_crypto_tokens =
      TELEHAND_FORWARD(crypto_key_exchange, return_crypto_tokens);

  p->transform.self = p;
  p->transform.api.encode_serialized_payload =
      TELEHAND_FORWARD(crypto_transform, encode_serialized_payload);
  p->transform.api.encode_datawriter_submessage = encodeWriterSubmessage;
  p->transform.api.encode_datareader_submessage =
      TELEHAND_FORWARD(crypto_transform, encode_datareader_submessage);
  p->transform.api.encode_rtps_message = TELEHAND_FORWARD(crypto_transform, encode_rtps_message);
  p->transform.api.decode_rtps_message = TELEHAND_FORWARD(crypto_transform, decode_rtps_message);
  p->transform.api.preprocess_secure_submsg =
      TELEHAND_FORWARD(crypto_transform, preprocess_secure_submsg);
  p->transform.api.decode_datawriter_submessage = decodeWriterSubmessage;
  p->transform.api.decode_datareader_submessage =
      TELEHAND_FORWARD(crypto_transform, decode_datareader_submessage);
  p->transform.api.decode_serialized_payload =
      TELEHAND_FORWARD(crypto_transform, decode_serialized_payload);

  p->base.self = p;
  p->base.api.gv = gv;
  p->base.api.crypto_key_factory = &p->factory.api;
  p->base.api.crypto_key_exchange = &p->exchange.api;
  p->base.api.crypto_transform = &p->transform.api;
  if (p->aes128 == nullptr || p->aes256 == nullptr) {
    fini(inner_context);
    dlclose(lib);
    delete p;
    return DDS_SECURITY_FAILED;
  }
  *context = &p->base.api;
  return DDS_SECURITY_SUCCESS;
}

__attribute__((visibility("default"))) int telehand_finalize_crypto(void* context) {
  if (context == nullptr) return DDS_SECURITY_SUCCESS;
  Plugin* p = static_cast<BaseBox*>(context)->self;
  const int rc = p->inner_finalize(p->inner_context);
  EVP_CIPHER_free(const_cast<EVP_CIPHER*>(p->aes128));
  EVP_CIPHER_free(const_cast<EVP_CIPHER*>(p->aes256));
  void* lib = p->library;
  delete p;
  dlclose(lib);
  return rc;
}

}  // extern "C"
