// Whole text files: written whole or not at all, and a failure says why.
#include "adapters/project_io/text_file.h"

#include <string>
#include <system_error>

#include <gtest/gtest.h>

#include "pipeline/core/error.h"
#include "tests/test_util.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

TEST(TextFile, WrittenThenReadBackAndReplacedWhole) {
  testing::TempDir dir;
  const fs::path path = dir.path() / "a.json";
  WriteTextFileAtomically(path, "first\n");
  WriteTextFileAtomically(path, "second, longer\n");
  EXPECT_EQ(ReadTextFile(path, "not found"), "second, longer\n");
  EXPECT_FALSE(fs::exists(dir.path() / "a.json.tmp"));
}

TEST(TextFile, AFileThatCannotBeWrittenSaysWhyAndLeavesNothing) {
  testing::TempDir dir;
  const fs::path path = dir.path() / "missing_dir" / "a.json";
  try {
    WriteTextFileAtomically(path, "text");
    FAIL() << "no error";
  } catch (const std::system_error& e) {
    EXPECT_EQ(e.code(), std::errc::no_such_file_or_directory);
    EXPECT_NE(std::string(e.what()).find(path.string() + ": cannot write file"), std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(dir.path() / "missing_dir"));
}

TEST(TextFile, AMissingFileIsTheUsersInputError) {
  testing::TempDir dir;
  try {
    ReadTextFile(dir.path() / "report.json", "report not found");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), (dir.path() / "report.json").string() + ": report not found");
  }
}

}  // namespace
}  // namespace omm
