#include "adapters/project_io/text_file.h"

#include <fstream>
#include <sstream>
#include <system_error>

#include "pipeline/core/error.h"

namespace omm {

void WriteTextFileAtomically(const std::filesystem::path& path, const std::string& text) {
  std::filesystem::path tmp = path;
  tmp += ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out << text;
    out.flush();
    if (!out) throw InputError(path.string(), "cannot write file");
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw InputError(path.string(), "cannot write file: " + ec.message());
  }
}

std::string ReadTextFile(const std::filesystem::path& path, const std::string& what_missing) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path.string(), what_missing);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

}  // namespace omm
