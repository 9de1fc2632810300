// SHA-256 (FIPS 180-4) through OpenSSL's libcrypto (EVP), for hashing a
// project's input files.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <string_view>

namespace omm {

class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;

  // Appends bytes to the message; may be called any number of times.
  void Update(const void* data, std::size_t size);
  void Update(std::string_view text) { Update(text.data(), text.size()); }
  // The digest as 64 lower-case hex digits. Ends the message: call once.
  std::string HexDigest();

 private:
  struct Context;
  std::unique_ptr<Context> context_;
};

// SHA-256 of `bytes`, 64 lower-case hex digits.
std::string Sha256Hex(std::string_view bytes);

}  // namespace omm
