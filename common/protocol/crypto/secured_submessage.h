// The secured data submessage of DDS Security 1.1 (9.5.3.3) with AES-GCM, as telehand's
// cryptography plugin (session_crypto.cpp) writes and reads it, and the key material of
// Cyclone's crypto tokens. Everything here takes outside bytes and checks their bounds
// (tests/fuzz/fuzz_secured_submessage.cpp).
//
//   SEC_PREFIX  id 0x31, flags, length 20 | kind (BE32) | key id (BE32) | session id (BE32)
//                                          | IV suffix (BE64)
//   SEC_BODY    id 0x30, flags, length 4+n | n (BE32) | AES-GCM(plain submessage), n bytes
//   SEC_POSTFIX id 0x32, flags, length 20+20k | GCM tag (16) | k (BE32) | k receiver MACs
//
// A submessage header's length is little-endian when flags bit 0 is set; the IV is the
// 12 bytes of session id and IV suffix as they stand on the wire.
#pragma once

#include <openssl/types.h>

#include <array>
#include <cstddef>
#include <cstdint>

namespace telehand::dds::crypto {

inline constexpr uint32_t kAes128Gcm = 2;
inline constexpr uint32_t kAes256Gcm = 4;
inline constexpr size_t kTagBytes = 16;
inline constexpr size_t kIvBytes = 12;

inline bool isGcm(uint32_t kind) { return kind == kAes128Gcm || kind == kAes256Gcm; }
inline size_t keyBytes(uint32_t kind) { return kind == kAes256Gcm ? 32 : 16; }

/// One writer's key material, as Cyclone's plugin puts it in a crypto token's
/// "dds.cryp.keymat": kind, salt, sender key id, key, receiver-specific key id (each array
/// length-prefixed, all big-endian).
struct KeyMaterial {
  uint32_t kind = 0;
  uint32_t sender_key_id = 0;
  std::array<uint8_t, 32> salt{};
  std::array<uint8_t, 32> key{};
};

/// Parses "dds.cryp.keymat". Only GCM key material without a receiver-specific key is taken
/// (false otherwise, and for anything short, long or inconsistent).
bool parseKeyMaterial(const uint8_t* data, size_t len, KeyMaterial& out);

/// Whether two key materials are the same key.
bool sameKey(const KeyMaterial& a, const KeyMaterial& b);

/// HMAC-SHA256(master key, "SessionKey" | master salt | session id (BE32)), cut to the key's
/// size. False when OpenSSL fails.
bool sessionKey(const KeyMaterial& km, uint32_t session_id, std::array<uint8_t, 32>& out);

/// A secured submessage's parts, pointing into the bytes parsed.
struct Secured {
  uint32_t kind = 0;
  uint32_t key_id = 0;
  uint32_t session_id = 0;
  const uint8_t* iv = nullptr;  ///< kIvBytes
  const uint8_t* cipher = nullptr;
  size_t n = 0;                  ///< cipher's length (that of the plain submessage)
  const uint8_t* tag = nullptr;  ///< kTagBytes
};

/// Parses SEC_PREFIX, SEC_BODY, SEC_POSTFIX from the start of `data`. False for anything
/// else, for a length out of bounds, and for an empty body.
bool parseSecured(const uint8_t* data, size_t len, Secured& out);

/// The size of the secured form of a plain submessage of n bytes.
inline size_t securedSize(size_t n) { return 4 + 20 + 4 + 4 + n + 4 + kTagBytes + 4; }

/// Writes the frame of a secured submessage of n bytes into `out` (securedSize(n) bytes):
/// headers, prefix, body length, an empty receiver-MAC list. Returns where the IV, the
/// cipher text and the tag go. n must be a multiple of 4 and at most 65,527.
struct Frame {
  uint8_t* iv;
  uint8_t* cipher;
  uint8_t* tag;
};
Frame writeFrame(uint8_t* out, size_t n, uint32_t kind, uint32_t key_id, uint32_t session_id,
                 uint64_t iv_suffix);

/// Encrypts `plain` (n bytes, n as the frame was written for) into the frame `f` with `ctx`,
/// an AES-GCM context already keyed with the session key; the IV is the frame's. False when
/// OpenSSL fails.
bool seal(EVP_CIPHER_CTX* ctx, const uint8_t* plain, size_t n, const Frame& f);

/// Decrypts `m` into `out` (m.n bytes) with `ctx`, an AES-GCM context already keyed with the
/// session key m's prefix names. False when the tag does not hold (or OpenSSL fails); `out`
/// then holds nothing to use.
bool unseal(EVP_CIPHER_CTX* ctx, const Secured& m, uint8_t* out);

}  // namespace telehand::dds::crypto
