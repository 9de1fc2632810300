#include "pipeline/orchestration/stage.h"

namespace omm {

const char* StageName(Stage stage) {
  switch (stage) {
    case Stage::kCalibrate: return "calibrate";
    case Stage::kMosaic: return "mosaic";
    case Stage::kMeasure: return "measure";
  }
  return "?";
}

std::vector<Stage> AllStages() { return {Stage::kCalibrate, Stage::kMosaic, Stage::kMeasure}; }

std::filesystem::path StageContext::Input(const std::string& name) const {
  std::error_code ec;
  if (std::filesystem::exists(staging_dir / name, ec)) return staging_dir / name;
  if (std::filesystem::exists(out_dir / name, ec)) return out_dir / name;
  return {};
}

}  // namespace omm
