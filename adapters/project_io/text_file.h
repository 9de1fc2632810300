// Whole text files, read and written for the project_io adapters.
#pragma once

#include <filesystem>
#include <string>

namespace omm {

// Writes `text` to a temporary file beside `path` and renames it into place,
// so a reader sees the old file or the complete new one, never a part.
// Throws std::system_error naming `path` and the system's reason (disk full,
// no such directory, no permission) if it cannot be written.
void WriteTextFileAtomically(const std::filesystem::path& path, const std::string& text);

// The file's bytes. Throws InputError naming `path` (with `what_missing`, e.g.
// "report not found") if it cannot be opened.
std::string ReadTextFile(const std::filesystem::path& path, const std::string& what_missing);

}  // namespace omm
