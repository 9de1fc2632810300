// Runner of the calibrate stage (see stage.h).
#include "pipeline/orchestration/stage.h"

namespace omm {

void RunCalibrateStage(StageContext& /*context*/) { throw StageNotBuiltError(Stage::kCalibrate); }

}  // namespace omm
