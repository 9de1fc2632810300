// The mosaic file and its world file: the world file's affine map puts every
// pixel centre where the grid (project-format.md's pixel convention) does.
#include "pipeline/mosaic/ortho_file.h"

#include <sstream>
#include <vector>

#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/text_file.h"
#include "tests/test_util.h"

namespace omm {
namespace {

TEST(WorldFile, NamesFollowGdal) {
  EXPECT_EQ(WorldFilePath("out/mosaic.png"), std::filesystem::path("out/mosaic.pgw"));
  EXPECT_EQ(WorldFilePath("out/mosaic.tif"), std::filesystem::path("out/mosaic.tfw"));
  EXPECT_EQ(WorldFilePath("out/mosaic.tiff"), std::filesystem::path("out/mosaic.tfw"));
  EXPECT_EQ(WorldFilePath("out/mosaic"), std::filesystem::path("out/mosaic.wld"));
}

TEST(WorldFile, WrittenBesideTheMosaicAndMapsPixelCentres) {
  OrthoGrid grid;
  grid.gsd_mm = 0.15;
  grid.origin_mm = Eigen::Vector2d(-459.75, 73.5);
  grid.size_px = Eigen::Vector2i(5, 3);
  StoredImage samples;
  samples.width = grid.size_px.x();
  samples.height = grid.size_px.y();
  samples.bit_depth = 8;
  samples.samples.assign(static_cast<size_t>(samples.width * samples.height), 100);

  const testing::TempDir dir;
  const std::filesystem::path path = dir.path() / "mosaic.png";
  const MosaicReport report = WriteOrthoMosaic(path, grid, samples);
  EXPECT_EQ(report.file, "mosaic.png");
  EXPECT_EQ(ReadGrayImage(path).width(), grid.size_px.x());

  std::istringstream text(ReadTextFile(dir.path() / "mosaic.pgw", "world file not found"));
  std::vector<double> v;
  for (double x; text >> x;) v.push_back(x);
  ASSERT_EQ(v.size(), 6u);
  const double a = v[0], d = v[1], b = v[2], e = v[3], c = v[4], f = v[5];
  for (const Eigen::Vector2d& col_row :
       {Eigen::Vector2d(0, 0), Eigen::Vector2d(4, 0), Eigen::Vector2d(0, 2), Eigen::Vector2d(4, 2),
        Eigen::Vector2d(2.5, 1.25)}) {
    const Eigen::Vector2d world(a * col_row.x() + b * col_row.y() + c,
                                d * col_row.x() + e * col_row.y() + f);
    // project-format.md: the centre of pixel (col, row) is at part-frame
    // (origin_x + (col + 0.5) gsd, origin_y - (row + 0.5) gsd).
    const Eigen::Vector2d expected(-459.75 + (col_row.x() + 0.5) * 0.15,
                                   73.5 - (col_row.y() + 0.5) * 0.15);
    EXPECT_NEAR(world.x(), expected.x(), 1e-12) << col_row.transpose();
    EXPECT_NEAR(world.y(), expected.y(), 1e-12) << col_row.transpose();
  }
}

}  // namespace
}  // namespace omm
