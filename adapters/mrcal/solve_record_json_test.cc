#include "adapters/mrcal/solve_record_json.h"

#include <gtest/gtest.h>

#include "adapters/mrcal/calibrate.h"
#include "adapters/mrcal/synthetic_plates.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

SolveRecord SolvedRecord() {
  const BoardSpec board;
  const testing::SyntheticPlates plates =
      testing::MakeSyntheticPlates(board, testing::TruthCamera(), 8, 390.0, 2);
  std::vector<PlateObservation> observations = plates.Observe(0.03, 5);
  observations[2].weight[7] = 0.0;
  observations[3].weight[9] = 0.5;
  CalibrationOptions options;
  options.width_px = 1600;
  options.height_px = 1200;
  options.optimize_calobject_warp = true;
  return CalibrateCamera(board, observations, options).record;
}

TEST(SolveRecordJson, RoundTripIsExact) {
  const SolveRecord record = SolvedRecord();
  const SolveRecord back = SolveRecordFromJson(SolveRecordToJson(record), "test");
  EXPECT_EQ(back.board.rows, record.board.rows);
  EXPECT_EQ(back.board.pitch_mm, record.board.pitch_mm);
  EXPECT_EQ(back.camera.lens_model, record.camera.lens_model);
  EXPECT_EQ(back.camera.intrinsics, record.camera.intrinsics);
  EXPECT_EQ(back.camera.width_px, record.camera.width_px);
  EXPECT_EQ(back.calobject_warp, record.calobject_warp);
  EXPECT_TRUE(back.problem.optimize_calobject_warp);
  ASSERT_EQ(back.images.size(), record.images.size());
  for (size_t i = 0; i < record.images.size(); ++i) {
    EXPECT_EQ(back.images[i].image, record.images[i].image);
    EXPECT_EQ(back.images[i].q_px, record.images[i].q_px);
    EXPECT_EQ(back.images[i].weight, record.images[i].weight);
    EXPECT_EQ(back.images[i].outlier, record.images[i].outlier);
    EXPECT_EQ(back.images[i].rt_cam_from_plate, record.images[i].rt_cam_from_plate);
  }
  // The same text again: the writer is deterministic.
  EXPECT_EQ(SolveRecordToJson(back), SolveRecordToJson(record));
}

TEST(SolveRecordJson, ReprocessingReproducesTheSummary) {
  const SolveRecord record = SolvedRecord();
  const CalibrationResult a = SummarizeSolve(record);
  const CalibrationResult b = SummarizeSolve(SolveRecordFromJson(SolveRecordToJson(record), "t"));
  EXPECT_EQ(a.rms_px, b.rms_px);
  EXPECT_EQ(a.num_observations_used, b.num_observations_used);
}

TEST(SolveRecordJson, MalformedInputNamesTheKey) {
  SolveRecord record = SolvedRecord();
  std::string text = SolveRecordToJson(record);
  const std::string model = "\"LENSMODEL_OPENCV8\"";
  text.replace(text.find(model), model.size(), "\"LENSMODEL_OPENCV4\"");
  try {
    SolveRecordFromJson(text, "out/solve.json");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.where(), "out/solve.json");
    EXPECT_NE(std::string(e.what()).find("camera"), std::string::npos) << e.what();
  }
  EXPECT_THROW(SolveRecordFromJson("{\"format\": 1}", "x"), InputError);
}

}  // namespace
}  // namespace omm
