// plane_scene.h's pure helpers.
#include "pipeline/core/plane_scene.h"

#include <gtest/gtest.h>

namespace omm {
namespace {

TEST(FreeIntrinsics, AreTheOnesNotHeld) {
  EXPECT_EQ(FreeIntrinsics(6, {0, 1, 4}), (std::vector<int>{2, 3, 5}));
  EXPECT_EQ(FreeIntrinsics(3, {}), (std::vector<int>{0, 1, 2}));
  EXPECT_TRUE(FreeIntrinsics(2, {0, 1}).empty());
}

// refine_intrinsics with held intrinsics: their information rows must be
// zero, the rest positive definite, the indices ascending and in range.
TEST(CheckPlaneBundleInput, HeldIntrinsicsMustHaveNoInformation) {
  PlaneBundleInput input;
  input.commanded_table_pos_mm = {{0, 0}, {100, 0}};
  PlaneBundleConfig config;
  config.refine_intrinsics = true;
  input.intrinsics_information = Eigen::MatrixXd::Identity(4, 4);
  input.intrinsics_information(1, 1) = 0;
  input.intrinsics_held = {1};
  EXPECT_EQ(CheckPlaneBundleInput(input, config, 4), "");
  input.intrinsics_held = {};
  EXPECT_NE(CheckPlaneBundleInput(input, config, 4).find("positive definite"), std::string::npos);
  input.intrinsics_held = {1, 2};
  EXPECT_NE(CheckPlaneBundleInput(input, config, 4).find("must be 0"), std::string::npos);
  input.intrinsics_held = {1, 1};
  EXPECT_NE(CheckPlaneBundleInput(input, config, 4).find("ascending"), std::string::npos);
  input.intrinsics_held = {0, 1, 2, 3};
  input.intrinsics_information.setZero();
  EXPECT_NE(CheckPlaneBundleInput(input, config, 4).find("every intrinsic held"),
            std::string::npos);
}

}  // namespace
}  // namespace omm
