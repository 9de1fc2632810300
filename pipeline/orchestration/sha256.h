// SHA-256 (FIPS 180-4), for hashing a project's input files. Small and
// self-contained; checked against the FIPS 180-4 / NIST example vectors.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

namespace omm {

class Sha256 {
 public:
  Sha256();
  // Appends bytes to the message; may be called any number of times.
  void Update(const void* data, std::size_t size);
  void Update(std::string_view text) { Update(text.data(), text.size()); }
  // The digest as 64 lower-case hex digits. Ends the message: call once.
  std::string HexDigest();

 private:
  void Block(const std::uint8_t* block);

  std::array<std::uint32_t, 8> state_;
  std::array<std::uint8_t, 64> buffer_{};
  std::size_t buffered_ = 0;
  std::uint64_t length_bytes_ = 0;
};

}  // namespace omm
