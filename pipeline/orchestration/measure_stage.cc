// Runner of the measure stage (see stage.h).
#include "pipeline/orchestration/stage.h"

namespace omm {

void RunMeasureStage(StageContext& /*context*/) { throw StageNotBuiltError(Stage::kMeasure); }

}  // namespace omm
