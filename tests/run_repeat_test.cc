// Users reprocess archived captures and compare the results byte for byte:
// two `omm run`s of one project on one build give the same bytes in every
// file of out/, report.json compared without its times (the members
// "seconds" and "timings_s"), report.html (which shows them) left out. The
// second run finds the heap laid out differently, so a result that depends
// on addresses, on the threads' order or on uninitialised memory is likely
// to show (slow: needs a render).
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <string>
#include <variant>

#include <gtest/gtest.h>

#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/orchestration/run_project.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

// `value` without its members named "seconds" or "timings_s", at any depth.
ReportValue WithoutTimes(const ReportValue& value) {
  if (const ReportObject* object = std::get_if<ReportObject>(&value.data())) {
    ReportObject kept;
    for (const auto& [key, member] : *object) {
      if (key != "seconds" && key != "timings_s") kept.emplace_back(key, WithoutTimes(member));
    }
    return kept;
  }
  if (const ReportValue::Array* array = std::get_if<ReportValue::Array>(&value.data())) {
    ReportValue::Array kept;
    for (const ReportValue& element : *array) kept.push_back(WithoutTimes(element));
    return kept;
  }
  return value;
}

void DropTimes(ReportObject* extra) {
  const ReportValue kept = WithoutTimes(*extra);
  *extra = *AsObject(&kept);
}

// report.json's text as written, but for its times (in the calibration's,
// the mosaic's and the measure stage's sections).
std::string ReportWithoutTimes(const fs::path& path) {
  Report report = ReadReportJson(path);
  DropTimes(&report.extra);
  if (report.calibration) DropTimes(&report.calibration->extra);
  if (report.mosaic) DropTimes(&report.mosaic->extra);
  return ReportToJson(report);
}

// Every file of out/ (path relative to it -> bytes), report.json without
// its times, report.html left out.
std::map<std::string, std::string> Results(const fs::path& out_dir) {
  std::map<std::string, std::string> files;
  for (const fs::directory_entry& entry : fs::recursive_directory_iterator(out_dir)) {
    if (!entry.is_regular_file()) continue;
    const std::string name = entry.path().lexically_relative(out_dir).string();
    if (name == "report.html") continue;
    if (name == "report.json") {
      files[name] = ReportWithoutTimes(entry.path());
    } else {
      std::ifstream in(entry.path(), std::ios::binary);
      files[name].assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
  }
  return files;
}

TEST(RunRepeat, TwoRunsGiveTheSameBytes) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 101, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "demo";
  testing::CopyProject(sim.project_dir, project_dir);
  RunProject(LoadProject(project_dir), RunOptions{});
  const std::map<std::string, std::string> first = Results(project_dir / "out");
  RunProject(LoadProject(project_dir), RunOptions{});
  const std::map<std::string, std::string> second = Results(project_dir / "out");

  // Not a comparison of two empty directories: the run wrote its results.
  for (const char* name : {"report.json", "camera.cameramodel", "mosaic.png", "mosaic/scene.json",
                           "calibration/solve.json"}) {
    EXPECT_EQ(first.count(name), 1u) << name;
  }
  ASSERT_EQ(first.size(), second.size());
  for (const auto& [name, bytes] : first) {
    const auto other = second.find(name);
    ASSERT_NE(other, second.end()) << name;
    // Not EXPECT_EQ: a 20 MB mosaic printed twice would drown the message.
    EXPECT_TRUE(bytes == other->second) << name << " differs between the two runs";
  }
}

}  // namespace
}  // namespace omm
