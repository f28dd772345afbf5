// libFuzzer target: the secured data submessages telehand's DDS Security cryptography plugin
// reads from the network (common/protocol/crypto/secured_submessage.h), and the key material
// of the crypto tokens it takes from other participants.
// Properties:
// - parseSecured on any bytes either refuses them or returns parts that lie within them;
//   parseKeyMaterial accepts only GCM key material of its exact size;
// - a plain submessage made from the input, sealed with a fixed key, parses back with the
//   same key id and session and unseals to the same bytes;
// - the same sealed submessage with one byte changed (where and how chosen by the input)
//   does not unseal to anything else: it is refused, or the changed byte was one of the
//   header flags bits the parser ignores and the plain bytes come back unchanged.
#include <openssl/evp.h>

#include <cstdlib>
#include <cstring>
#include <vector>

#include "../../common/protocol/crypto/secured_submessage.h"

using namespace telehand::dds::crypto;

namespace {

void check(bool ok) {
  if (!ok) std::abort();
}

struct Ctx {
  EVP_CIPHER_CTX* c = EVP_CIPHER_CTX_new();
  ~Ctx() { EVP_CIPHER_CTX_free(c); }
};

/// The whole read path of a received submessage: parse, the key it names, unseal.
bool receive(const uint8_t* data, size_t size, const KeyMaterial& km, std::vector<uint8_t>& out) {
  Secured m;
  if (!parseSecured(data, size, m)) return false;
  check(m.iv >= data && m.iv + kIvBytes <= data + size);
  check(m.cipher >= data && m.cipher + m.n <= data + size);
  check(m.tag >= data && m.tag + kTagBytes <= data + size);
  if (m.kind != km.kind || m.key_id != km.sender_key_id) return false;
  std::array<uint8_t, 32> key{};
  Ctx ctx;
  check(sessionKey(km, m.session_id, key));
  check(EVP_DecryptInit_ex(ctx.c, EVP_aes_256_gcm(), nullptr, key.data(), nullptr) == 1);
  out.assign(m.n, 0);
  return unseal(ctx.c, m, out.data());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  // Any bytes as a secured submessage and as key material.
  Secured any;
  if (parseSecured(data, size, any)) {
    check(any.n > 0 && any.cipher + any.n <= data + size && any.tag + kTagBytes <= data + size);
  }
  KeyMaterial parsed;
  if (parseKeyMaterial(data, size, parsed)) {
    check(isGcm(parsed.kind) && size == 24 + 2 * keyBytes(parsed.kind));
  }
  // Seal a plain submessage made from the input, read it back, then change one byte.
  if (size < 3) return 0;
  KeyMaterial km;
  km.kind = kAes256Gcm;
  km.sender_key_id = 0x01020304;
  for (size_t i = 0; i < 32; ++i) {
    km.salt[i] = static_cast<uint8_t>(i * 7 + 1);
    km.key[i] = static_cast<uint8_t>(i * 13 + 5);
  }
  const size_t where = data[0] | (size_t{data[1]} << 8);
  const uint8_t how = data[2] == 0 ? 1 : data[2];
  std::vector<uint8_t> plain(data + 3, data + size);
  plain.resize((plain.size() + 4) / 4 * 4, 0);  // a submessage: a non-empty multiple of 4
  if (plain.size() > 60000) return 0;
  const uint32_t session = 0xabcdef01u ^ static_cast<uint32_t>(size);
  std::array<uint8_t, 32> key{};
  check(sessionKey(km, session, key));
  Ctx ctx;
  check(EVP_EncryptInit_ex(ctx.c, EVP_aes_256_gcm(), nullptr, key.data(), nullptr) == 1);
  std::vector<uint8_t> wire(securedSize(plain.size()));
  const Frame f = writeFrame(wire.data(), plain.size(), km.kind, km.sender_key_id, session,
                             0x1122334455667788ull + size);
  check(seal(ctx.c, plain.data(), plain.size(), f));
  std::vector<uint8_t> back;
  check(receive(wire.data(), wire.size(), km, back) && back == plain);

  const size_t at = where % wire.size();
  wire[at] ^= how;
  const bool flags_byte = at == 1 || at == 25 || at == 33 + plain.size();
  const bool ignored = flags_byte && (how & 0x01) == 0;  // only bit 0 (endianness) is read
  if (receive(wire.data(), wire.size(), km, back)) {
    check(ignored && back == plain);
  } else {
    check(!ignored);
  }
  return 0;
}
