// Runner of the mosaic stage (see stage.h).
#include "pipeline/orchestration/stage.h"

namespace omm {

void RunMosaicStage(StageContext& /*context*/) { throw StageNotBuiltError(Stage::kMosaic); }

}  // namespace omm
