#include "adapters/openssl/sha256.h"

#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace omm {
namespace {

std::string Hash(std::string_view text) {
  Sha256 sha;
  sha.Update(text);
  return sha.HexDigest();
}

// FIPS 180-4 / NIST CSRC example vectors.
TEST(Sha256, NistVectors) {
  EXPECT_EQ(Hash(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(Hash("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(Hash("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  EXPECT_EQ(Hash(std::string(1000000, 'a')),
            "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

// Padding edge cases around the 56- and 64-byte block limits, fed in 7-byte
// chunks. Expected digests from Python's hashlib.sha256 of the same bytes.
TEST(Sha256, PaddingEdgesInChunks) {
  const std::vector<std::pair<size_t, std::string>> cases = {
      {55, "8aa994584139d128848eeebc4e815639ba5ab6e6e39574195a63ac4f14f7c43b"},
      {56, "ad574708f75c044c9b85de64cb568ee7711ff4f36448c6242f053ba8f6cc2b63"},
      {63, "280ed3e8ff1df845b2e7dfe6ac6cee817bef20e783cc65abc41b818b4d2fe076"},
      {64, "c6ab9724ade5b6a7a1edfffb12f3aa9181351355af8fd08c919952ad211339dd"},
      {65, "788367c73c7ddf4c53f65e68cc0d943e6227ab55b0e78ba63ace822b1c6301c0"}};
  for (const auto& [size, digest] : cases) {
    std::string message(size, '\0');
    for (size_t i = 0; i < size; ++i) message[i] = static_cast<char>((i * 31 + 7) % 256);
    Sha256 chunked;
    for (size_t at = 0; at < size; at += 7) chunked.Update(message.substr(at, 7));
    EXPECT_EQ(chunked.HexDigest(), digest) << size << " bytes";
  }
}

TEST(Sha256, OneCallFormEqualsTheStream) { EXPECT_EQ(Sha256Hex("abc"), Hash("abc")); }

}  // namespace
}  // namespace omm
