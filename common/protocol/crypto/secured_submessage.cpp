#include "secured_submessage.h"

#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include <cstring>

namespace telehand::dds::crypto {
namespace {

constexpr uint8_t kSmidSecBody = 0x30;
constexpr uint8_t kSmidSecPrefix = 0x31;
constexpr uint8_t kSmidSecPostfix = 0x32;
constexpr uint8_t kFlagLittleEndian = 0x01;
constexpr size_t kPrefixBytes = 20;

uint32_t readBe32(const uint8_t* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | p[3];
}
void writeBe32(uint8_t* p, uint32_t v) {
  p[0] = static_cast<uint8_t>(v >> 24);
  p[1] = static_cast<uint8_t>(v >> 16);
  p[2] = static_cast<uint8_t>(v >> 8);
  p[3] = static_cast<uint8_t>(v);
}

/// The submessage with id `id` at `p` (bounded by `end`): its body [body, body + len); moves
/// `p` past it.
bool submessage(const uint8_t*& p, const uint8_t* end, uint8_t id, const uint8_t*& body,
                size_t& len) {
  if (end - p < 4 || p[0] != id) return false;
  len = (p[1] & kFlagLittleEndian) ? (size_t{p[2]} | (size_t{p[3]} << 8))
                                   : ((size_t{p[2]} << 8) | size_t{p[3]});
  if (len % 4 != 0 || static_cast<size_t>(end - p - 4) < len) return false;
  body = p + 4;
  p = body + len;
  return true;
}

uint8_t* putHeader(uint8_t* p, uint8_t id, size_t len) {
  p[0] = id;
  p[1] = kFlagLittleEndian;
  p[2] = static_cast<uint8_t>(len);
  p[3] = static_cast<uint8_t>(len >> 8);
  return p + 4;
}

}  // namespace

bool parseKeyMaterial(const uint8_t* p, size_t left, KeyMaterial& out) {
  if (p == nullptr) return false;
  auto u32 = [&](uint32_t& v) {
    if (left < 4) return false;
    v = readBe32(p);
    p += 4;
    left -= 4;
    return true;
  };
  auto bytes = [&](std::array<uint8_t, 32>& dst, size_t n) {
    uint32_t len = 0;
    if (!u32(len) || len != n || left < n) return false;
    std::memcpy(dst.data(), p, n);
    p += n;
    left -= n;
    return true;
  };
  uint32_t receiver_key_id = 0;
  uint32_t receiver_key_len = 0;
  if (!u32(out.kind) || !isGcm(out.kind)) return false;
  const size_t n = keyBytes(out.kind);
  return bytes(out.salt, n) && u32(out.sender_key_id) && bytes(out.key, n) &&
         u32(receiver_key_id) && receiver_key_id == 0 && u32(receiver_key_len) &&
         receiver_key_len == 0 && left == 0;
}

bool sameKey(const KeyMaterial& a, const KeyMaterial& b) {
  return a.kind == b.kind && a.sender_key_id == b.sender_key_id && a.salt == b.salt &&
         a.key == b.key;
}

bool sessionKey(const KeyMaterial& km, uint32_t session_id, std::array<uint8_t, 32>& out) {
  const size_t n = keyBytes(km.kind);
  uint8_t msg[10 + 32 + 4];
  std::memcpy(msg, "SessionKey", 10);
  std::memcpy(msg + 10, km.salt.data(), n);
  writeBe32(msg + 10 + n, session_id);
  uint8_t md[EVP_MAX_MD_SIZE];
  unsigned int md_len = 0;
  const bool ok = HMAC(EVP_sha256(), km.key.data(), static_cast<int>(n), msg, 10 + n + 4, md,
                       &md_len) != nullptr &&
                  md_len >= n;
  if (ok) std::memcpy(out.data(), md, n);
  OPENSSL_cleanse(md, sizeof md);
  return ok;
}

bool parseSecured(const uint8_t* data, size_t len, Secured& out) {
  if (data == nullptr) return false;
  const uint8_t* q = data;
  const uint8_t* end = data + len;
  const uint8_t* prefix = nullptr;
  const uint8_t* body = nullptr;
  const uint8_t* post = nullptr;
  size_t prefix_len = 0;
  size_t body_len = 0;
  size_t post_len = 0;
  if (!submessage(q, end, kSmidSecPrefix, prefix, prefix_len) || prefix_len < kPrefixBytes ||
      !submessage(q, end, kSmidSecBody, body, body_len) || body_len < 4 ||
      !submessage(q, end, kSmidSecPostfix, post, post_len) || post_len < kTagBytes + 4) {
    return false;
  }
  const size_t n = readBe32(body);
  const size_t macs = readBe32(post + kTagBytes);
  if (n == 0 || n > body_len - 4 || macs > (post_len - kTagBytes - 4) / 20) return false;
  out.kind = readBe32(prefix);
  out.key_id = readBe32(prefix + 4);
  out.session_id = readBe32(prefix + 8);
  out.iv = prefix + 8;
  out.cipher = body + 4;
  out.n = n;
  out.tag = post;
  return true;
}

Frame writeFrame(uint8_t* out, size_t n, uint32_t kind, uint32_t key_id, uint32_t session_id,
                 uint64_t iv_suffix) {
  uint8_t* q = putHeader(out, kSmidSecPrefix, kPrefixBytes);
  writeBe32(q, kind);
  writeBe32(q + 4, key_id);
  uint8_t* iv = q + 8;
  writeBe32(iv, session_id);
  writeBe32(iv + 4, static_cast<uint32_t>(iv_suffix >> 32));
  writeBe32(iv + 8, static_cast<uint32_t>(iv_suffix));
  q = putHeader(q + kPrefixBytes, kSmidSecBody, 4 + n);
  writeBe32(q, static_cast<uint32_t>(n));
  uint8_t* cipher = q + 4;
  uint8_t* tag = putHeader(cipher + n, kSmidSecPostfix, kTagBytes + 4);
  writeBe32(tag + kTagBytes, 0);
  return {iv, cipher, tag};
}

bool seal(EVP_CIPHER_CTX* ctx, const uint8_t* plain, size_t n, const Frame& f) {
  int len = 0;
  int fin = 0;
  return n <= 0xffff && EVP_EncryptInit_ex(ctx, nullptr, nullptr, nullptr, f.iv) == 1 &&
         EVP_EncryptUpdate(ctx, f.cipher, &len, plain, static_cast<int>(n)) == 1 &&
         static_cast<size_t>(len) == n && EVP_EncryptFinal_ex(ctx, f.cipher + len, &fin) == 1 &&
         fin == 0 &&
         EVP_CIPHER_CTX_ctrl(ctx, EVP_CTRL_GCM_GET_TAG, static_cast<int>(kTagBytes), f.tag) == 1;
}

bool unseal(EVP_CIPHER_CTX* ctx, const Secured& m, uint8_t* out) {
  int len = 0;
  int fin = 0;
  uint8_t tag[kTagBytes];
  std::memcpy(tag, m.tag, kTagBytes);
  return m.n <= 0xffff && EVP_DecryptInit_ex(ctx, nullptr, nullptr, nullptr, m.iv) == 1 &&
         EVP_CIPHER_CTX_ctrl(ctx, EVP_CTRL_GCM_SET_TAG, static_cast<int>(kTagBytes), tag) == 1 &&
         EVP_DecryptUpdate(ctx, out, &len, m.cipher, static_cast<int>(m.n)) == 1 &&
         static_cast<size_t>(len) == m.n && EVP_DecryptFinal_ex(ctx, out + len, &fin) == 1;
}

}  // namespace telehand::dds::crypto
