// RegisterTiles on a real mosaic: a confocal microscope's 3 x 4 tiles of a
// speckled metal surface with ~10 % overlap (../shared/data/
// lscm_speckle_3x4_tiles, read in place; see its README). There is no true
// geometry, but two registrations give each tile's offset: Fiji's (phase
// correlation) and the data's authors' (digital image correlation without
// distortion correction, TileConfiguration_uncorrected.txt). They differ by
// up to ~2.5 px per pair (the microscope's distortion is strong at the tile
// edges, where the overlaps are). The pairwise translations our matches imply
// must agree with the authors' within 1.5 px.
//
// The planar bundle adjustment is not asserted here: the seed
// (plane_seed.h) takes the distance from the perspective between tiles,
// which a microscope's nearly telecentric view does not have.
#include "pipeline/mosaic/register_tiles.h"
#include "pipeline/mosaic/tile_features.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "pipeline/core/statistics.h"
#include "tests/test_util.h"

namespace omm {
namespace {

using testing::SharedDataDir;

// Fiji TileConfiguration: "name.tif; ; (x, y)" per tile, file order.
std::vector<std::pair<std::string, Eigen::Vector2d>> ReadTileConfiguration(
    const std::filesystem::path& path) {
  std::ifstream in(path);
  const std::regex line_re(R"(^\s*([^;#]+\.tif)\s*;\s*;\s*\(\s*([-0-9.eE]+)\s*,\s*([-0-9.eE]+)\s*\))");
  std::vector<std::pair<std::string, Eigen::Vector2d>> tiles;
  std::string line;
  std::smatch m;
  while (std::getline(in, line)) {
    if (std::regex_search(line, m, line_re))
      tiles.emplace_back(m[1].str(), Eigen::Vector2d(std::stod(m[2].str()), std::stod(m[3].str())));
  }
  return tiles;
}

TEST(RegisterTilesReal, LscmSpeckleOffsetsAgreeWithPublishedRegistration) {
  const std::filesystem::path dir = SharedDataDir() / "lscm_speckle_3x4_tiles";
  // The data sits beside the repository, not in it: a clone elsewhere skips.
  if (!std::filesystem::is_directory(dir)) GTEST_SKIP() << "no " << dir;
  const auto nominal = ReadTileConfiguration(dir / "TileConfiguration.txt");
  const auto registered = ReadTileConfiguration(dir / "TileConfiguration.registered.txt");
  std::map<std::string, Eigen::Vector2d> authors_by_name;
  for (const auto& [name, pos] : ReadTileConfiguration(dir / "TileConfiguration_uncorrected.txt"))
    authors_by_name[name] = pos;
  ASSERT_EQ(authors_by_name.size(), 12u);
  std::vector<Eigen::Vector2d> authors;  // in the order of `nominal`
  ASSERT_EQ(nominal.size(), 12u);
  ASSERT_EQ(registered.size(), 12u);
  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> commanded;
  for (size_t i = 0; i < nominal.size(); ++i) {
    ASSERT_EQ(nominal[i].first, registered[i].first);
    ASSERT_EQ(authors_by_name.count(nominal[i].first), 1u);
    authors.push_back(authors_by_name[nominal[i].first]);
    std::string png = nominal[i].first;
    png.replace(png.size() - 4, 4, ".png");
    tiles.push_back(ReadGrayImage(dir / png).pixels);
    EXPECT_FALSE(BlankImageLevel(tiles.back()).has_value()) << png;  // a real capture
    // The stage grid in its own units (one "mm" per nominal px), y flipped:
    // Fiji's y runs down the image, the table's Y up (a camera looking down
    // sees the table's axes mirrored, which the plane seed checks).
    commanded.push_back(Eigen::Vector2d(nominal[i].second.x(), -nominal[i].second.y()));
  }
  // A pinhole camera 1000 mm away with a 1000 px focal length: 1 px per mm.
  CameraModel camera;
  camera.lens_model = "LENSMODEL_PINHOLE";
  camera.intrinsics = Eigen::Vector4d(1000, 1000, 511.5, 511.5);
  camera.width_px = camera.height_px = 1024;
  RegisterTilesOptions options;
  options.motion.min_overlap_fraction = 0.05;  // the neighbours overlap by 10 %
  options.probe_search_radius_px = 12;
  options.use_apriltags = false;
  options.bundle.max_usable_rms_px = 2.0;  // the microscope's distortion is not modelled
  options.compute_covariance = false;
  // Fiji's positions deviate from the grid by up to ~6 px.
  const TileRegistration reg = RegisterTiles(tiles, commanded, 3.0, camera, options);
  std::printf("%s\n  features %.2f s, matching %.2f s, adjustment %.2f s\n", reg.brief.c_str(),
              reg.features_seconds, reg.matching_seconds, reg.adjustment_seconds);

  // Median image translation of each pair's matches against Fiji's: content
  // at q in tile a is at q - (pos_b - pos_a) in tile b.
  std::map<std::pair<int, int>, std::vector<Eigen::Vector2d>> shifts;
  for (size_t o = 0; o < reg.input.observations.size(); ++o) {
    const TrackObservation& obs = reg.input.observations[o];
    const TrackObservation& anchor = reg.input.observations[reg.track_anchor_observation[obs.track]];
    if (&obs == &anchor) continue;
    shifts[{anchor.tile, obs.tile}].push_back(obs.q_px - anchor.q_px);
  }
  int neighbour_pairs = 0;
  for (const PairRegistration& pair : reg.pairs) {
    const Eigen::Vector2d step = nominal[pair.tile_b].second - nominal[pair.tile_a].second;
    if (step.norm() > 925) continue;  // only grid neighbours overlap usefully (10 %)
    ++neighbour_pairs;
    EXPECT_TRUE(pair.usable) << pair.tile_a << "-" << pair.tile_b;
    std::vector<Eigen::Vector2d>& s = shifts[{pair.tile_a, pair.tile_b}];
    ASSERT_GE(s.size(), 15u) << pair.tile_a << "-" << pair.tile_b;
    Eigen::Vector2d median;
    for (int k = 0; k < 2; ++k) {
      std::vector<double> v;
      for (const Eigen::Vector2d& d : s) v.push_back(d(k));
      median(k) = Median(std::move(v));
    }
    const Eigen::Vector2d fiji = registered[pair.tile_a].second - registered[pair.tile_b].second;
    const Eigen::Vector2d dic = authors[pair.tile_a] - authors[pair.tile_b];
    std::printf("  pair %d-%d: %zu matches, shift (%.2f, %.2f) px, authors (%.2f, %.2f), "
                "Fiji (%.2f, %.2f)\n",
                pair.tile_a, pair.tile_b, s.size(), median.x(), median.y(), dic.x(), dic.y(),
                fiji.x(), fiji.y());
    EXPECT_LT((median - dic).norm(), 1.5) << pair.tile_a << "-" << pair.tile_b;
  }
  EXPECT_EQ(neighbour_pairs, 17);  // 3 rows x 3 + 2 x 4 columns
}

// NIST MIST's 5 x 5 phase-contrast tiles (../shared/data/mist_phase_contrast_5x5):
// crops of one image, 245 x 183 px, stepped ~230 x ~172 px, so neighbours
// overlap by only ~15 and ~11 px, narrower than a template (31 px): no pair
// can be matched. The registration must say so and place no tile by its
// images, never misplace one silently.
TEST(RegisterTilesReal, MistOverlapsNarrowerThanATemplateAreReported) {
  const std::filesystem::path dir = SharedDataDir() / "mist_phase_contrast_5x5";
  if (!std::filesystem::is_directory(dir)) GTEST_SKIP() << "no " << dir;
  std::ifstream in(dir / "ground_truth_global_positions.csv");
  std::vector<ImageF> tiles;
  std::vector<Eigen::Vector2d> commanded;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#' || line.rfind("file", 0) == 0) continue;
    std::stringstream fields(line);
    std::string file, row, col;
    std::getline(fields, file, ',');
    std::getline(fields, row, ',');
    std::getline(fields, col, ',');
    tiles.push_back(ReadGrayImage(dir / file).pixels);
    // Dim 16-bit phase contrast (median 0.4 % of full scale), yet a picture.
    EXPECT_FALSE(BlankImageLevel(tiles.back()).has_value()) << file;
    // The nominal grid, y up (as above), in px as "mm".
    commanded.emplace_back(230.0 * std::stoi(col), -172.0 * std::stoi(row));
  }
  ASSERT_EQ(tiles.size(), 25u);
  CameraModel camera;  // 1 px per "mm", as above
  camera.lens_model = "LENSMODEL_PINHOLE";
  camera.intrinsics = Eigen::Vector4d(1000, 1000, 122, 91);
  camera.width_px = 245;
  camera.height_px = 183;
  RegisterTilesOptions options;
  options.motion.min_overlap_fraction = 0.01;  // let the 6 % overlaps be tried
  options.use_apriltags = false;
  options.compute_covariance = false;
  // The crops drift up to ~21 px from the grid.
  const TileRegistration reg = RegisterTiles(tiles, commanded, 10.0, camera, options);
  std::printf("%s\n", reg.brief.c_str());
  EXPECT_FALSE(reg.usable);
  EXPECT_EQ(reg.pairs.size(), 40u);  // the grid's neighbours: 5 x 4 + 4 x 5
  for (const PairRegistration& pair : reg.pairs) {
    EXPECT_FALSE(pair.usable) << pair.tile_a << "-" << pair.tile_b;
    EXPECT_EQ(pair.num_used, 0) << pair.tile_a << "-" << pair.tile_b;
  }
  EXPECT_EQ(reg.tiles_held_by_prior.size(), 25u);
  EXPECT_NE(reg.brief.find("held by the table prior alone"), std::string::npos) << reg.brief;
}

}  // namespace
}  // namespace omm
