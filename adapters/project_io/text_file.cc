#include "adapters/project_io/text_file.h"

#include <cerrno>
#include <fstream>
#include <sstream>
#include <system_error>

#include "pipeline/core/error.h"

namespace omm {

void WriteTextFileAtomically(const std::filesystem::path& path, const std::string& text) {
  std::filesystem::path tmp = path;
  tmp += ".tmp";
  errno = 0;  // a failed write's reason (WriteError), not an earlier call's
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out << text;
    out.flush();
    if (!out) throw WriteError(path, "cannot write file");
  }
  std::error_code failed;
  std::filesystem::rename(tmp, path, failed);
  if (failed) {
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    throw std::system_error(failed, path.string() + ": cannot write file");
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
