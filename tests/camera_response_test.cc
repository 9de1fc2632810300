// `omm run` on cameras whose images are not the simulator's linear ones.
//
// Gamma (GenICam's Gamma: pixel = linear^gamma): every edge's mid-level
// crossing assumes linear intensities. Rendered projects whose images are
// gamma-encoded read every hole small (the crossing moves towards the dark
// side: seed 281's diameters were 0.07-0.08 raw px small at gamma 0.8, 9-17
// of their sigmas), while centres, which move symmetrically, stay. With
// camera.gamma the images are linearized when read and the diameters come
// out as from a linear camera.
//
// Saturation: where the surface beside a rim clips at full scale, the rim
// step's mid-level crossing moves; such rims are left out or refused.
//
// Sample bits: 12-bit samples stored unshifted in 16-bit files.
//
// Black level: a camera whose black level is set above the dark scene clips
// it to 0, and the mosaic marks the pixels no tile sees as 0. The holes'
// openings over a black table were then taken for unseen pixels, and every
// hole was "cut by the mosaic border".
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <initializer_list>
#include <map>
#include <string>

#include <gtest/gtest.h>

#include <Eigen/Core>

#include "adapters/opencv/image_io.h"
#include "adapters/png/png_codec.h"
#include "adapters/project_io/project_reader.h"
#include "adapters/project_io/report_json.h"
#include "pipeline/orchestration/run_project.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

constexpr double kGamma = 0.8;

// The 8-bit image file at `path` with each sample x replaced by encode(x).
template <typename Encode>
void ReencodeFile(const fs::path& path, Encode encode) {
  StoredImage image = ReadStoredImage(path);
  ASSERT_EQ(image.bit_depth, 8) << path;
  for (std::uint8_t& sample : image.samples) sample = encode(sample);
  testing::WriteTextFile(path, EncodeGrayPng(image));
}

// Every image of `folders` (8-bit: the rendered files') so.
template <typename Encode>
void Reencode(const fs::path& project_dir, Encode encode,
              std::initializer_list<const char*> folders = {"calib", "tiles"}) {
  for (const char* folder : folders) {
    for (const fs::directory_entry& entry : fs::directory_iterator(project_dir / folder))
      ReencodeFile(entry.path(), encode);
  }
}

// Overexposed 2.2 times, clipped at 255.
std::uint8_t Overexposed(std::uint8_t x) {
  return static_cast<std::uint8_t>(std::min(std::lround(2.2 * x), 255L));
}

// As a camera of kGamma would have stored them.
void EncodeWithGamma(const fs::path& project_dir) {
  Reencode(project_dir, [](std::uint8_t x) {
    return static_cast<std::uint8_t>(std::lround(255.0 * std::pow(x / 255.0, kGamma)));
  });
}

// Each found hole's diameter error against the truth, raw px.
std::vector<double> DiameterErrorsRawPx(const fs::path& project_dir, const SimulationTruth& truth) {
  const Report report = ReadReportJson(project_dir / "out" / "report.json");
  std::vector<double> errors;
  if (!report.features) return errors;
  for (const FeatureReport& f : *report.features) {
    for (const HoleTruth& hole : truth.holes) {
      if (hole.name != f.name || !f.diameter_mm) continue;
      errors.push_back((*f.diameter_mm - hole.diameter_mm) / testing::RawPxMm(truth));
    }
  }
  return errors;
}

double Mean(const std::vector<double>& v) {
  return Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size())).mean();
}

TEST(CameraGamma, LinearizedImagesMeasureDiametersAsALinearCamera) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path given = dir.path() / "given", ignored = dir.path() / "ignored";
  for (const fs::path& project_dir : {given, ignored}) {
    testing::CopyProject(sim.project_dir, project_dir);
    EncodeWithGamma(project_dir);
  }
  testing::ReplaceInFile(given / "project.yaml", "camera:\n", "camera:\n  gamma: 0.8\n");
  ASSERT_DOUBLE_EQ(LoadProject(given).camera.gamma, kGamma);
  RunProject(LoadProject(given), RunOptions{});
  RunProject(LoadProject(ignored), RunOptions{});
  const std::vector<double> with = DiameterErrorsRawPx(given, sim.truth);
  const std::vector<double> without = DiameterErrorsRawPx(ignored, sim.truth);
  ASSERT_EQ(with.size(), sim.truth.holes.size());
  ASSERT_EQ(without.size(), sim.truth.holes.size());
  for (size_t i = 0; i < with.size(); ++i)
    std::printf("hole %zu: diameter %+.4f raw px linearized, %+.4f not\n", i, with[i], without[i]);
  // Issue 5's bound for the demo preset, each; together unbiased to the
  // scatter of a linear camera's (0.01-0.02 raw px on demo seeds).
  for (double e : with) EXPECT_LT(std::abs(e), 0.05);
  EXPECT_LT(std::abs(Mean(with)), 0.02);
  // Not linearized, every hole reads small.
  EXPECT_LT(Mean(without), -0.04);
}

// `omm run` on project_dir: every feature found (unless not all_found) and
// every measurement made within 3 of its sigmas of the truth (issue 5's 0.05 raw px does not hold
// here for the linear 8-bit camera either: its dia_hole_14 is 0.050 off,
// with a sigma of 0.026). The report.
Report RunAndCheckAgainstTruth(const fs::path& project_dir, const SimulationTruth& truth,
                               bool all_found = true) {
  RunProject(LoadProject(project_dir), RunOptions{});
  const Report run = ReadReportJson(project_dir / "out" / "report.json");
  EXPECT_TRUE(run.features && run.measurements);
  if (!run.features || !run.measurements) return run;
  for (const FeatureReport& f : *run.features)
    EXPECT_TRUE(f.centre_mm || !all_found) << f.name << ": " << f.error;
  for (const MeasurementReport& m : *run.measurements) {
    EXPECT_TRUE((m.value_mm && m.sigma_mm) || !all_found) << m.name << ": " << m.error;
    if (!m.value_mm || !m.sigma_mm) continue;
    for (const MeasurementTruth& t : truth.measurements) {
      if (t.name != m.name) continue;
      const double error_mm = *m.value_mm - t.value_mm;
      std::printf("%s %+.4f raw px, %+.2f sigma\n", m.name.c_str(),
                  error_mm / testing::RawPxMm(truth), error_mm / *m.sigma_mm);
      EXPECT_LT(std::abs(error_mm), 3.0 * *m.sigma_mm) << m.name;
    }
  }
  return run;
}

// The rendered table (0.04 of white) is at 8-10 of 255 in the demo's
// images; a black level 12 above the simulator's clips it, in the holes'
// openings and beyond the part, to 0. The walls and the surface stay above
// it, so the rims' mid-level crossings are where a linear camera has them.
constexpr int kBlackLevel = 12;

TEST(CameraBlackLevel, HolesOverABlackTableAreMeasured) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "black";
  testing::CopyProject(sim.project_dir, project_dir);
  Reencode(project_dir,
           [](std::uint8_t x) { return static_cast<std::uint8_t>(std::max(x - kBlackLevel, 0)); });
  // The premise: a good share of each tile is black.
  for (const fs::directory_entry& entry : fs::directory_iterator(project_dir / "tiles")) {
    const StoredImage tile = ReadStoredImage(entry.path());
    const auto black = std::count(tile.samples.begin(), tile.samples.end(), 0);
    EXPECT_GT(black, tile.samples.size() / 50) << entry.path();
  }

  const Report run = RunAndCheckAgainstTruth(project_dir, sim.truth);
  ASSERT_TRUE(run.measurements);

  // `omm measure` alone reads the 16-bit mosaic.png back: black stays seen.
  RunOptions measure_alone;
  measure_alone.stages = {Stage::kMeasure};
  RunProject(LoadProject(project_dir), measure_alone);
  const Report again = ReadReportJson(project_dir / "out" / "report.json");
  ASSERT_TRUE(again.measurements);
  ASSERT_EQ(again.measurements->size(), run.measurements->size());
  for (size_t i = 0; i < run.measurements->size(); ++i) {
    EXPECT_EQ((*again.measurements)[i].value_mm, (*run.measurements)[i].value_mm)
        << (*run.measurements)[i].name;
  }
}

// An overexposed capture: the demo's tiles at 2.2 times their exposure
// clip half their pixels, the surface beside every rim among them. Each
// hole is refused as saturated in the tile that sees it, where fitting the
// mosaic (which does not mark clipped pixels) read diameters 0.37 raw px off
// on seed 281.
TEST(CameraSaturation, HolesWhoseRimsAreClippedAreRefused) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "overexposed";
  testing::CopyProject(sim.project_dir, project_dir);
  Reencode(project_dir, Overexposed, {"tiles"});
  RunProject(LoadProject(project_dir), RunOptions{});
  const Report report = ReadReportJson(project_dir / "out" / "report.json");
  ASSERT_TRUE(report.features);
  ASSERT_EQ(report.features->size(), sim.truth.holes.size());
  for (const FeatureReport& f : *report.features) {
    EXPECT_FALSE(f.centre_mm) << f.name;
    EXPECT_EQ(f.error.rfind("rim saturated", 0), 0u) << f.name << ": " << f.error;
    EXPECT_FALSE(Member(f.extra, "fit")) << f.name << ": a failed fit's brief is its error";
  }
}

// One tile overexposed among the others (an exposure that went wrong once):
// tile_r1c0 at 2.2 times its exposure, the surface beside the rims it sees
// clipped. It is the first tile tried (the one that sees it deepest inside)
// for two holes that other tiles see whole too, and the only one for a
// third. A hole that another tile sees whole is measured there, with
// tile_r1c0 left out and said so. One that only tile_r1c0 sees whole is
// measured in the tiles that see part of its rim (partial views,
// hole_views.h), its diameter within 3 of its sigmas of the truth; before,
// it was refused.
// Before, a hole was refused whenever the first tile tried failed so; and
// the exposure compensation, whose gauge is the brightest tile, lifted the
// other tiles above 1 where it clipped, so that their tile patches, clamped
// at 1, read the diameters 0.3-0.4 raw px small (4-9 sigmas).
TEST(CameraSaturation, HolesClippedInOneTileAreMeasuredInTheOthers) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path as_rendered = dir.path() / "as_rendered", one = dir.path() / "one";
  testing::CopyProject(sim.project_dir, as_rendered);
  testing::CopyProject(sim.project_dir, one);
  const std::string bright = "tile_r1c0.png";
  ReencodeFile(one / "tiles" / bright, Overexposed);

  // The tiles each hole is measured in when none is clipped.
  RunProject(LoadProject(as_rendered), RunOptions{});
  const Report reference = ReadReportJson(as_rendered / "out" / "report.json");
  ASSERT_TRUE(reference.features);
  std::map<std::string, std::string> views;
  for (const FeatureReport& f : *reference.features) {
    const std::string* note = AsString(Member(f.extra, "views"));
    ASSERT_TRUE(note) << f.name;
    views[f.name] = *note;
  }

  const Report run = RunAndCheckAgainstTruth(one, sim.truth, /*all_found=*/false);
  ASSERT_TRUE(run.features);
  int num_left_out = 0, num_partial = 0;
  for (const FeatureReport& f : *run.features) {
    const std::string& seen_in = views[f.name];
    const bool in_bright = seen_in.find(bright) != std::string::npos;
    const bool only_bright = seen_in.rfind("measured in 1 tile: " + bright, 0) == 0;
    if (only_bright) {
      const std::string* note = AsString(Member(f.extra, "views"));
      ASSERT_TRUE(f.centre_mm && f.diameter_mm && f.diameter_sigma_mm && note)
          << f.name << ": " << f.error;
      std::printf("%s: %s\n", f.name.c_str(), note->c_str());
      EXPECT_NE(note->find("part of the rim (those that see it whole clipped it)"),
                std::string::npos)
          << *note;
      EXPECT_NE(note->find(bright + " left out: rim saturated"), std::string::npos) << *note;
      for (const HoleTruth& hole : sim.truth.holes) {
        if (hole.name != f.name) continue;
        const double error_mm = *f.diameter_mm - hole.diameter_mm;
        std::printf("%s diameter %+.4f raw px, %+.2f sigma\n", f.name.c_str(),
                    error_mm / testing::RawPxMm(sim.truth), error_mm / *f.diameter_sigma_mm);
        EXPECT_LT(std::abs(error_mm), 3.0 * *f.diameter_sigma_mm) << f.name;
        ++num_partial;
      }
      continue;
    }
    EXPECT_TRUE(f.centre_mm) << f.name << " (" << seen_in << "): " << f.error;
    const std::string* note = AsString(Member(f.extra, "views"));
    ASSERT_TRUE(note) << f.name;
    if (in_bright && note->find(bright + " left out: rim saturated") != std::string::npos)
      ++num_left_out;
  }
  std::printf("%d holes measured without %s, %d in partial views (seen whole by it alone)\n",
              num_left_out, bright.c_str(), num_partial);
  EXPECT_GT(num_left_out, 0);
  EXPECT_EQ(num_partial, 1);

  // The report says which tile is overexposed, and how much.
  ASSERT_TRUE(run.mosaic);
  const ReportValue::Array* tiles = AsArray(Member(run.mosaic->extra, "tiles"));
  ASSERT_TRUE(tiles);
  for (const ReportValue& row : *tiles) {
    const ReportObject& tile = *AsObject(&row);
    const std::string image = *AsString(Member(tile, "image"));
    const double fraction = AsNumber(Member(tile, "saturated_fraction")).value_or(-1.0);
    std::printf("%s: %.1f %% at full scale\n", image.c_str(), 100.0 * fraction);
    if (image == bright) {
      EXPECT_GT(fraction, 0.1);
    } else {
      EXPECT_EQ(fraction, 0.0) << image;
    }
  }

  // The mosaic keeps the other tiles' exposure: the gauge is the median
  // tile, and the overexposed one's clipped samples are drawn (at full
  // scale) only where no other tile sees the point. With the brightest tile
  // as the gauge, 50 % of the mosaic was at full scale, the rest 2.2 times
  // as bright as the unaltered project's.
  const ImageF altered = ReadGrayImage(one / "out" / "mosaic.png").pixels;
  const ImageF unaltered = ReadGrayImage(as_rendered / "out" / "mosaic.png").pixels;
  ASSERT_EQ(altered.rows(), unaltered.rows());
  ASSERT_EQ(altered.cols(), unaltered.cols());
  std::vector<double> ratio;
  Eigen::Index num_covered = 0, num_full_scale = 0;
  for (Eigen::Index i = 0; i < altered.size(); ++i) {
    if (!(unaltered.data()[i] > 0.0f)) continue;
    ++num_covered;
    if (altered.data()[i] >= 1.0f) {
      ++num_full_scale;
    } else {
      ratio.push_back(altered.data()[i] / unaltered.data()[i]);
    }
  }
  std::nth_element(ratio.begin(), ratio.begin() + ratio.size() / 2, ratio.end());
  const double median_ratio = ratio[ratio.size() / 2];
  const double full_scale = static_cast<double>(num_full_scale) / num_covered;
  std::printf("mosaic: %.2f %% at full scale, median ratio to the unaltered one's %.4f\n",
              100.0 * full_scale, median_ratio);
  // Where tile_r1c0 alone sees the part (~3 % of the mosaic), clipped.
  EXPECT_LT(full_scale, 0.03);
  // The median tile may move by one: the demo's gains are 0.95-1.05.
  EXPECT_NEAR(median_ratio, 1.0, 0.05);
}

// Partial views locate a hole but tie no tiles in the mosaic (hole_ties.h):
// each is fitted on its own arc of the rim. tile_r0c0 at 2.2 times its
// exposure: a hole it alone sees whole is measured in two tiles that see
// part of its rim, and is not among the mosaic's hole ties, which holes
// seen whole by two tiles or more still make.
TEST(CameraSaturation, PartialViewsTieNoTiles) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "r0c0";
  testing::CopyProject(sim.project_dir, project_dir);
  ReencodeFile(project_dir / "tiles" / "tile_r0c0.png", Overexposed);
  const Report run = RunAndCheckAgainstTruth(project_dir, sim.truth, /*all_found=*/false);
  ASSERT_TRUE(run.features && run.mosaic);

  std::vector<std::string> partial;  // holes measured in two partial views or more
  for (const FeatureReport& f : *run.features) {
    const std::string* note = AsString(Member(f.extra, "views"));
    if (note && note->find(" tiles that see part of the rim") != std::string::npos) {
      ASSERT_TRUE(f.diameter_mm) << f.name << ": " << f.error;
      std::printf("%s: %s\n", f.name.c_str(), note->c_str());
      partial.push_back(f.name);
    }
  }
  ASSERT_FALSE(partial.empty());

  const ReportObject* hole_ties = AsObject(Member(run.mosaic->extra, "hole_ties"));
  ASSERT_NE(hole_ties, nullptr);
  const ReportValue::Array* ties = AsArray(Member(*hole_ties, "ties"));
  const ReportValue::Array* dropped = AsArray(Member(*hole_ties, "dropped"));
  ASSERT_TRUE(ties && dropped);
  std::printf("%s\n", AsString(Member(*hole_ties, "brief"))->c_str());
  EXPECT_FALSE(ties->empty());
  std::vector<std::string> tied;
  for (const ReportValue& tie : *ties)
    tied.push_back(*AsString(Member(*AsObject(&tie), "feature")));
  for (const ReportValue& name : *dropped) tied.push_back(*AsString(&name));
  for (const std::string& name : partial)
    EXPECT_EQ(std::count(tied.begin(), tied.end(), name), 0) << name << " ties tiles";

  // Located as well as the holes seen whole, to the 0.05 raw px
  // RMS (#4).
  double sum_squares = 0.0;
  const auto errors = testing::HoleCentreErrorsAfterSimilarity(run, sim.truth);
  for (const auto& [name, error_mm] : errors) {
    const double error_px = error_mm / testing::RawPxMm(sim.truth);
    std::printf("%s: %.4f raw px from the truth\n", name.c_str(), error_px);
    sum_squares += error_px * error_px;
    if (std::find(partial.begin(), partial.end(), name) != partial.end()) {
      EXPECT_LT(error_px, 0.05) << name;
    }
  }
  ASSERT_FALSE(errors.empty());
  EXPECT_LT(std::sqrt(sum_squares / static_cast<double>(errors.size())), 0.05);
}

// A 12-bit camera whose samples its SDK stores unshifted in 16-bit files:
// the images read 16 times too dark (at most 0.045 of full scale on the
// demo), and no plate was found in calib/. They are read as 12-bit samples.
TEST(CameraSampleBits, TwelveBitSamplesInSixteenBitFilesAreMeasured) {
  const testing::CachedProject sim = testing::SimulatedProject("demo", 104, 14);
  testing::TempDir dir;
  const fs::path project_dir = dir.path() / "mono12";
  testing::CopyProject(sim.project_dir, project_dir);
  for (const char* folder : {"calib", "tiles"}) {
    for (const fs::directory_entry& entry : fs::directory_iterator(project_dir / folder)) {
      const StoredImage eight = ReadStoredImage(entry.path());
      ASSERT_EQ(eight.bit_depth, 8) << entry.path();
      StoredImage twelve{eight.width, eight.height, 16,
                         std::vector<std::uint8_t>(2 * eight.samples.size())};
      auto* samples = reinterpret_cast<std::uint16_t*>(twelve.samples.data());
      for (size_t i = 0; i < eight.samples.size(); ++i)
        samples[i] = static_cast<std::uint16_t>(16 * eight.samples[i]);
      testing::WriteTextFile(entry.path(), EncodeGrayPng(twelve));
    }
  }
  ASSERT_EQ(LoadProject(project_dir).sample_bits, 12);
  RunAndCheckAgainstTruth(project_dir, sim.truth);
}

}  // namespace
}  // namespace omm
