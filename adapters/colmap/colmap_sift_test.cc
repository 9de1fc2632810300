// COLMAP's SIFT as a feature source: the database reading on a hand-made
// database (exact blob and pair_id decoding), the failures, and a real run of
// the installed `colmap` binary on four simulated tiles, scored against the
// simulator's truth geometry.
#include "adapters/colmap/colmap_sift.h"

#include <sqlite3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "adapters/mrcal/lens.h"
#include "adapters/opencv/image_io.h"
#include "pipeline/core/error.h"
#include "pipeline/core/statistics.h"
#include "pipeline/simulate/simulation.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

// ------------------------------------------------------- a hand-made database

// The tables omm reads, as COLMAP 3.8 creates them (src/base/database.cc).
constexpr const char* kColmapSchema = R"sql(
CREATE TABLE images (image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL,
  name TEXT NOT NULL UNIQUE, camera_id INTEGER NOT NULL, prior_qw REAL, prior_qx REAL,
  prior_qy REAL, prior_qz REAL, prior_tx REAL, prior_ty REAL, prior_tz REAL,
  CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < 2147483647));
CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB);
CREATE TABLE two_view_geometries (pair_id INTEGER PRIMARY KEY NOT NULL,
  rows INTEGER NOT NULL, cols INTEGER NOT NULL, data BLOB, config INTEGER NOT NULL,
  F BLOB, E BLOB, H BLOB, qvec BLOB, tvec BLOB);
)sql";

constexpr std::int64_t kPairIdBase = 2147483647;

class TestDatabase {
 public:
  explicit TestDatabase(const fs::path& path) : path_(path) {
    fs::remove(path);
    EXPECT_EQ(sqlite3_open(path.c_str(), &db_), SQLITE_OK);
    Exec(kColmapSchema);
  }
  ~TestDatabase() { sqlite3_close(db_); }

  void Exec(const std::string& sql) {
    char* message = nullptr;
    EXPECT_EQ(sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &message), SQLITE_OK)
        << (message ? message : "");
    sqlite3_free(message);
  }
  void AddImage(std::int64_t id, const std::string& name) {
    Exec("INSERT INTO images (image_id, name, camera_id) VALUES (" + std::to_string(id) + ", '" +
         name + "', 1)");
  }
  // rows x cols float32, row-major.
  void AddKeypoints(std::int64_t id, int cols, const std::vector<float>& data) {
    Insert("INSERT INTO keypoints VALUES (?, ?, ?, ?)", id, static_cast<int>(data.size()) / cols,
           cols, data.data(), data.size() * 4);
  }
  // Index pairs (into image_id1's, image_id2's keypoints), image_id1 < image_id2.
  void AddTwoView(std::int64_t image_id1, std::int64_t image_id2,
                  const std::vector<std::uint32_t>& data, int cols = 2) {
    Insert(
        "INSERT INTO two_view_geometries (pair_id, rows, cols, data, config) "
        "VALUES (?, ?, ?, ?, 2)",
        image_id1 * kPairIdBase + image_id2, static_cast<int>(data.size()) / cols, cols,
        data.data(), data.size() * 4);
  }

 private:
  void Insert(const char* sql, std::int64_t id, int rows, int cols, const void* blob,
              size_t bytes) {
    sqlite3_stmt* stmt = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(db_, sql, -1, &stmt, nullptr), SQLITE_OK);
    sqlite3_bind_int64(stmt, 1, id);
    sqlite3_bind_int(stmt, 2, rows);
    sqlite3_bind_int(stmt, 3, cols);
    sqlite3_bind_blob(stmt, 4, blob, static_cast<int>(bytes), SQLITE_TRANSIENT);
    EXPECT_EQ(sqlite3_step(stmt), SQLITE_DONE) << sqlite3_errmsg(db_);
    sqlite3_finalize(stmt);
  }

  fs::path path_;
  sqlite3* db_ = nullptr;
};

fs::path TempPath(const std::string& name) { return fs::temp_directory_path() / name; }

// Three tiles whose image ids are out of order, one image that is not a tile,
// keypoints with 6, 4 and 2 columns, and pairs whose image order is the
// reverse of the tile order. The values are exact in float32.
TEST(ReadColmapDatabaseMatches, DecodesBlobsAndPairIdsExactly) {
  const fs::path path = TempPath("omm_colmap_sift_test_db.db");
  {
    TestDatabase db(path);
    db.AddImage(7, "tile_0.png");
    db.AddImage(3, "tile_1.png");
    db.AddImage(1, "other.png");
    db.AddImage(5, "tile_2.png");
    // image 7 (tile 0): x, y, a11, a12, a21, a22.
    db.AddKeypoints(7, 6,
                    {10.5f, 20.25f, 1, 0, 0, 1,  //
                     100.5f, 0.5f, 2, 0, 0, 2,   //
                     1599.5f, 1199.5f, 3, 0, 0, 3});
    // image 3 (tile 1): x, y, scale, orientation.
    db.AddKeypoints(3, 4,
                    {0.5f, 0.75f, 1.5f, 0.1f,  //
                     30.0f, 40.0f, 2.5f, 0.2f});
    // image 5 (tile 2): x, y.
    db.AddKeypoints(5, 2, {5.5f, 6.5f, 7.5f, 8.5f, 9.5f, 10.5f, 11.5f, 12.5f});
    db.AddKeypoints(1, 2, {1.0f, 1.0f});
    // (3, 7): image 3 = tile 1, image 7 = tile 0 -> tiles (0, 1), swapped.
    db.AddTwoView(3, 7, {1, 2, 0, 0});
    // (5, 7): tile 2 with tile 0 -> tiles (0, 2), swapped.
    db.AddTwoView(5, 7, {3, 1});
    // (3, 5): tile 1 with tile 2 -> tiles (1, 2), in order.
    db.AddTwoView(3, 5, {1, 0, 0, 2, 1, 3});
    // The non-tile image, and a pair without inliers: ignored.
    db.AddTwoView(1, 7, {0, 0});
    db.AddTwoView(1, 3, {});
  }
  const ColmapDatabaseMatches m =
      ReadColmapDatabaseMatches(path, {"tile_0.png", "tile_1.png", "tile_2.png"});
  EXPECT_EQ(m.num_keypoints, (std::vector<int>{3, 2, 4}));
  ASSERT_EQ(m.pairs.size(), 3u);
  EXPECT_EQ(m.num_matches, 2 + 1 + 3);

  const ColmapPairMatches& p01 = m.pairs[0];
  EXPECT_EQ(p01.tile_a, 0);
  EXPECT_EQ(p01.tile_b, 1);
  Eigen::Matrix2Xd a(2, 2), b(2, 2);
  a << 1599.0, 10.0, 1199.0, 19.75;  // tile 0's keypoints 2, 0 minus 0.5
  b << 29.5, 0.0, 39.5, 0.25;        // tile 1's keypoints 1, 0 minus 0.5
  EXPECT_EQ(p01.q_a_px, a);
  EXPECT_EQ(p01.q_b_px, b);

  const ColmapPairMatches& p02 = m.pairs[1];
  EXPECT_EQ(p02.tile_a, 0);
  EXPECT_EQ(p02.tile_b, 2);
  EXPECT_EQ(p02.q_a_px, Eigen::Matrix2Xd(Eigen::Vector2d(100.0, 0.0)));
  EXPECT_EQ(p02.q_b_px, Eigen::Matrix2Xd(Eigen::Vector2d(11.0, 12.0)));

  const ColmapPairMatches& p12 = m.pairs[2];
  EXPECT_EQ(p12.tile_a, 1);
  EXPECT_EQ(p12.tile_b, 2);
  a.resize(2, 3);
  b.resize(2, 3);
  a << 29.5, 0.0, 29.5, 39.5, 0.25, 39.5;
  b << 5.0, 9.0, 11.0, 6.0, 10.0, 12.0;
  EXPECT_EQ(p12.q_a_px, a);
  EXPECT_EQ(p12.q_b_px, b);
  fs::remove(path);
}

TEST(ReadColmapDatabaseMatches, RejectsMalformedContent) {
  const fs::path path = TempPath("omm_colmap_sift_test_bad.db");
  const std::vector<std::string> names = {"a.png", "b.png"};
  auto expect_error = [&](const std::string& fragment) {
    try {
      ReadColmapDatabaseMatches(path, names);
      ADD_FAILURE() << "no error, expected '" << fragment << "'";
    } catch (const InputError& error) {
      EXPECT_NE(std::string(error.what()).find(fragment), std::string::npos) << error.what();
    }
  };
  {
    TestDatabase db(path);
    db.AddImage(1, "a.png");
    db.AddImage(2, "b.png");
    db.AddKeypoints(1, 2, {1, 2});
    db.AddKeypoints(2, 2, {1, 2});
    db.AddTwoView(1, 2, {0, 1});  // keypoint 1 of b does not exist
  }
  expect_error("out of range");
  {
    TestDatabase db(path);
    db.AddImage(1, "a.png");
    db.Exec("INSERT INTO keypoints VALUES (1, 2, 2, x'00000000')");  // 4 bytes for 4 floats
  }
  expect_error("a blob of 4 bytes for 2 x 2");
  {
    TestDatabase db(path);
    db.AddImage(1, "a.png");
    db.AddKeypoints(1, 3, {1, 2, 3});
  }
  expect_error("expected 2, 4 or 6");
  {
    TestDatabase db(path);
    db.Exec("DROP TABLE two_view_geometries");
  }
  expect_error("not a COLMAP database");
  fs::remove(path);
  expect_error("no such database file");
}

// ------------------------------------------------------- options, failures

TEST(ColmapSiftOptions, CheckNamesTheBadField) {
  EXPECT_EQ(ColmapSiftOptions().Check(), "");
  ColmapSiftOptions o;
  o.max_num_features = 0;
  EXPECT_NE(o.Check().find("max_num_features"), std::string::npos);
  o = ColmapSiftOptions();
  o.timeout_seconds = 0;
  EXPECT_NE(o.Check().find("timeout_seconds"), std::string::npos);
  o = ColmapSiftOptions();
  o.first_octave = -2;
  EXPECT_NE(o.Check().find("first_octave"), std::string::npos);
  o = ColmapSiftOptions();
  o.sample_bits = 17;
  EXPECT_NE(o.Check().find("sample_bits"), std::string::npos);
  EXPECT_THROW(ColmapSiftMatches({"a.png", "b.png"}, o), InputError);
}

TEST(ColmapSiftMatches, MissingBinaryIsAReportedFailure) {
  const fs::path dir = TempPath("omm_colmap_sift_test_missing");
  fs::create_directories(dir);
  std::vector<fs::path> tiles = {dir / "a.png", dir / "b.png"};
  for (const fs::path& t : tiles) std::ofstream(t) << "not read";
  ColmapSiftOptions options;
  options.binary = "/nonexistent/colmap";
  const ColmapSiftResult r = ColmapSiftMatches(tiles, options);
  EXPECT_FALSE(r.usable);
  EXPECT_NE(r.brief.find("cannot run '/nonexistent/colmap'"), std::string::npos) << r.brief;
  EXPECT_THROW(ColmapSiftMatches({dir / "a.png", dir / "missing.png"}, ColmapSiftOptions()),
               InputError);
  fs::remove_all(dir);
}

// A stand-in for colmap (a shell script): its banner, then `feature_extractor`
// runs `extractor_body`.
fs::path FakeColmap(const fs::path& dir, const std::string& extractor_body) {
  fs::path path = dir / "fake_colmap";
  std::ofstream(path) << "#!/bin/sh\n"
                      << "if [ \"$1\" = -h ]; then echo 'COLMAP 9.9 -- fake'; exit 0; fi\n"
                      << extractor_body << "\n";
  fs::permissions(path, fs::perms::owner_all);
  return path;
}

TEST(ColmapSiftMatches, FailingOrHangingColmapIsAReportedFailure) {
  const fs::path dir = TempPath("omm_colmap_sift_test_fake");
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::vector<fs::path> tiles = {dir / "a.png", dir / "b.png"};
  for (const fs::path& t : tiles) std::ofstream(t) << "not read";
  ColmapSiftOptions options;
  options.binary = FakeColmap(dir, "echo 'first line'; echo 'E: image unreadable' >&2; exit 3");
  ColmapSiftResult r = ColmapSiftMatches(tiles, options);
  EXPECT_FALSE(r.usable);
  EXPECT_EQ(r.colmap_version, "COLMAP 9.9");
  EXPECT_NE(r.brief.find("feature_extractor failed: exit code 3; log: E: image unreadable"),
            std::string::npos)
      << r.brief;

  options.binary = FakeColmap(dir, "sleep 30");
  options.timeout_seconds = 0.5;
  const auto start = std::chrono::steady_clock::now();
  r = ColmapSiftMatches(tiles, options);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_FALSE(r.usable);
  EXPECT_NE(r.brief.find("feature_extractor failed: timed out"), std::string::npos) << r.brief;
  EXPECT_LT(seconds, 5.0);
  fs::remove_all(dir);
}

// ------------------------------------------------------- the real binary

Eigen::Isometry3d TruthPose(const SimulationTruth& truth, int tile) {
  Eigen::Isometry3d pose = truth.cam_from_part;
  const Eigen::Vector2d& t = truth.tiles[tile].actual_mm;
  pose.translation() += truth.cam_from_part.linear() * Eigen::Vector3d(t.x(), t.y(), 0);
  return pose;
}

// Where tile b sees the part point (Z = 0) that tile a sees at q_a: the truth
// camera's ray through q_a cut with the part plane, projected into tile b.
Eigen::Matrix2Xd TransferThroughTruth(const SimulationTruth& truth, int tile_a, int tile_b,
                                      const Eigen::Matrix2Xd& q_a_px) {
  const CameraModel& camera = truth.camera.model;
  Eigen::Matrix3Xd v;
  EXPECT_TRUE(UnprojectPixels(camera, q_a_px, &v));
  const Eigen::Isometry3d cam_a = TruthPose(truth, tile_a), cam_b = TruthPose(truth, tile_b);
  const Eigen::Isometry3d b_from_a = cam_b * cam_a.inverse();
  // Part plane in camera a: n . p = d with n the part's Z axis.
  const Eigen::Vector3d n = cam_a.linear().col(2);
  const double d = n.dot(cam_a.translation());
  Eigen::Matrix3Xd p_b(3, v.cols());
  for (Eigen::Index k = 0; k < v.cols(); ++k)
    p_b.col(k) = b_from_a * (v.col(k) * (d / n.dot(v.col(k))));
  Eigen::Matrix2Xd q_b;
  EXPECT_TRUE(ProjectPoints(camera, p_b, &q_b));
  return q_b;
}

// Isolated Gaussian blobs (sigma 1.8-3.0 px, >= 16 px apart, at random
// sub-pixel centres) on gray, sampled at omm's pixel centres: each blob is
// symmetric about its centre, so its DoG extremum (a SIFT keypoint) lies at
// the centre in omm pixels. The second image is the first moved by `shift_px`.
class BlobImages {
 public:
  static constexpr int kWidth = 400, kHeight = 300;
  const Eigen::Vector2d shift_px{13, -9};

  BlobImages() {
    std::mt19937 random(7);
    auto uniform = [&](double lo, double hi) { return lo + (hi - lo) * (random() / 4294967296.0); };
    for (int gy = 0; gy < 11; ++gy) {
      for (int gx = 0; gx < 15; ++gx) {
        blobs_.push_back({{30.0 + 24 * gx + uniform(-4, 4), 30.0 + 24 * gy + uniform(-4, 4)},
                          uniform(1.8, 3.0),
                          (uniform(0, 1) < 0.5 ? -1 : 1) * uniform(0.25, 0.45)});
      }
    }
  }
  // The first (moved = false) or second image, in [0, 1].
  ImageF Render(bool moved) const {
    const Eigen::Vector2d offset = moved ? shift_px : Eigen::Vector2d::Zero();
    ImageF image = ImageF::Constant(kHeight, kWidth, 0.5f);
    for (const Blob& b : blobs_) {
      const Eigen::Vector2d c = b.center_px + offset;
      for (int y = 0; y < kHeight; ++y) {
        for (int x = 0; x < kWidth; ++x) {
          const double r2 = (Eigen::Vector2d(x, y) - c).squaredNorm();
          image(y, x) +=
              static_cast<float>(b.amplitude * std::exp(-r2 / (2 * b.sigma_px * b.sigma_px)));
        }
      }
    }
    return image;
  }

  // The two images as `dir`/a.png and b.png (a fresh `dir`), their samples
  // times `scale` at `bit_depth` bits.
  std::vector<fs::path> Write(const fs::path& dir, float scale, int bit_depth) const {
    fs::remove_all(dir);
    fs::create_directories(dir);
    const std::vector<fs::path> paths = {dir / "a.png", dir / "b.png"};
    WriteGrayImage(paths[0], Render(false) * scale, bit_depth);
    WriteGrayImage(paths[1], Render(true) * scale, bit_depth);
    return paths;
  }

  // `r` matched the two images, and the blobs' own keypoints (those within
  // 1 px of a centre) lie at their centres: each matched keypoint of the
  // first image against its blob's centre, its match in the second image
  // against it moved by shift_px.
  void ExpectMatchesAtTheCentres(const ColmapSiftResult& r) const {
    ASSERT_TRUE(r.usable) << r.brief;
    ASSERT_EQ(r.matches.pairs.size(), 1u);
    const ColmapPairMatches& pair = r.matches.pairs[0];
    std::vector<double> errors;
    Eigen::Vector2d mean_error = Eigen::Vector2d::Zero();
    for (Eigen::Index k = 0; k < pair.q_a_px.cols(); ++k) {
      Eigen::Vector2d nearest = blobs_.front().center_px;
      for (const Blob& b : blobs_) {
        if ((b.center_px - pair.q_a_px.col(k)).norm() < (nearest - pair.q_a_px.col(k)).norm())
          nearest = b.center_px;
      }
      const Eigen::Vector2d e = pair.q_a_px.col(k) - nearest;
      if (e.norm() > 1.0) continue;
      errors.push_back(e.norm());
      mean_error += e;
      EXPECT_LT((pair.q_b_px.col(k) - pair.q_a_px.col(k) - shift_px).norm(), 0.1);
    }
    ASSERT_GE(errors.size(), blobs_.size() / 2);
    mean_error /= static_cast<double>(errors.size());
    std::printf("%zu matches, %zu at blob centres: median distance %.3f px, mean (%.3f, %.3f) px\n",
                static_cast<size_t>(pair.q_a_px.cols()), errors.size(), Median(errors),
                mean_error.x(), mean_error.y());
    // Measured: median 0.013 px, mean below 0.001 px (an ideal, symmetric,
    // 8-bit-quantised blob). A half-pixel convention error would put every
    // one 0.71 px away; the bounds leave ~4x headroom and catch 0.05 px of
    // bias.
    EXPECT_LT(Median(errors), 0.05);
    EXPECT_LT(mean_error.norm(), 0.02);
  }

 private:
  struct Blob {
    Eigen::Vector2d center_px;
    double sigma_px, amplitude;
  };
  std::vector<Blob> blobs_;
};

// The pixel convention, through the real binary. Between overlapping tiles
// (nearly a translation) a constant offset of every keypoint cancels, so the
// truth test below cannot see it; here the keypoints' absolute positions are
// checked on the blobs.
TEST(ColmapSiftMatches, RealColmapKeypointsAreInOmmPixels) {
  const BlobImages blobs;
  const fs::path dir = TempPath("omm_colmap_sift_test_blobs");
  const std::vector<fs::path> paths = blobs.Write(dir, 1.0f, 8);
  ColmapSiftOptions options;
  options.keep_work_dir = true;
  const ColmapSiftResult r = ColmapSiftMatches(paths, options);
  std::printf("%s\n", r.brief.c_str());
  EXPECT_TRUE(fs::is_regular_file(r.work_dir / "database.db"));
  EXPECT_TRUE(fs::is_regular_file(r.work_dir / "colmap.log"));
  fs::remove_all(r.work_dir);
  blobs.ExpectMatchesAtTheCentres(r);
  fs::remove_all(dir);
}

// A 12-bit camera's samples stored unshifted in 16-bit files. COLMAP keeps
// their high byte (at most 15 of 255 here) and finds no match; told the
// sample bits, it is given 8-bit copies over 4095 and matches the blobs as
// from 8-bit files.
TEST(ColmapSiftMatches, TwelveBitSamplesInSixteenBitFilesAreMatched) {
  const BlobImages blobs;
  const fs::path dir = TempPath("omm_colmap_sift_test_mono12");
  const std::vector<fs::path> paths = blobs.Write(dir, 4095.0f / 65535.0f, 16);
  ColmapSiftOptions options;
  const ColmapSiftResult unaware = ColmapSiftMatches(paths, options);
  std::printf("as 16-bit samples: %s\n", unaware.brief.c_str());
  EXPECT_EQ(unaware.matches.num_matches, 0);

  options.sample_bits = 12;
  const ColmapSiftResult r = ColmapSiftMatches(paths, options);
  std::printf("as 12-bit samples: %s\n", r.brief.c_str());
  blobs.ExpectMatchesAtTheCentres(r);
  fs::remove_all(dir);
}

// Given pairs, only those are matched (colmap matches_importer): tile 2, a
// copy of tile 0, matches both others, but only pair 0-1 is asked for.
TEST(ColmapSiftMatches, OnlyTheGivenPairsAreMatched) {
  const BlobImages blobs;
  const fs::path dir = TempPath("omm_colmap_sift_test_pairs");
  std::vector<fs::path> paths = blobs.Write(dir, 1.0f, 8);
  paths.push_back(dir / "c.png");
  fs::copy_file(paths[0], paths[2]);
  const ColmapSiftResult all = ColmapSiftMatches(paths, ColmapSiftOptions());
  std::printf("every pair: %s\n", all.brief.c_str());
  ASSERT_TRUE(all.usable) << all.brief;
  EXPECT_EQ(all.matches.pairs.size(), 3u);
  const ColmapSiftResult listed = ColmapSiftMatches(paths, ColmapSiftOptions(), {{1, 0}});
  std::printf("pair 0-1: %s\n", listed.brief.c_str());
  blobs.ExpectMatchesAtTheCentres(listed);  // one pair, moved by the shift: 0-1
  EXPECT_THROW(ColmapSiftMatches(paths, ColmapSiftOptions(), {{0, 3}}), InputError);
  EXPECT_THROW(ColmapSiftMatches(paths, ColmapSiftOptions(), {{2, 2}}), InputError);
  fs::remove_all(dir);
}

// The four tiles of the top-left corner of a demo project (all six pairs
// overlap: 35-45 % side by side, ~15 % diagonally), rendered as 8-bit PNGs.
TEST(ColmapSiftMatches, RealColmapMatchesAgreeWithTheTruth) {
  SimulationOptions sim;
  sim.preset = "demo";
  sim.seed = 5;
  const SimulationPlan plan = PlanSimulation(sim);
  const SimulationTruth& truth = plan.truth;
  const CameraModel& camera = truth.camera.model;
  const auto start = std::chrono::steady_clock::now();
  RayTableSummary ray_summary;
  const RayTable rays = ComputeRayTable(camera, {0, 0, camera.width_px, camera.height_px},
                                        RayOptionsFor(sim), &ray_summary);
  ASSERT_TRUE(ray_summary.ok);
  const ProjectRenderer renderer(plan);
  const fs::path dir = TempPath("omm_colmap_sift_test_tiles");
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::vector<int> truth_tile;  // our tile index -> the truth's
  std::vector<fs::path> paths;
  for (size_t i = 0; i < truth.tiles.size(); ++i) {
    if (truth.tiles[i].grid_row > 1 || truth.tiles[i].grid_col > 1) continue;
    truth_tile.push_back(static_cast<int>(i));
    paths.push_back(dir / truth.tiles[i].image);
    WriteGrayImage(paths.back(), renderer.RenderTile(static_cast<int>(i), rays),
                   plan.sensor.bit_depth);
  }
  ASSERT_EQ(paths.size(), 4u);
  std::printf("rendering: %.1f s\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());

  const ColmapSiftOptions options;
  const ColmapSiftResult r = ColmapSiftMatches(paths, options);
  std::printf("%s\n", r.brief.c_str());
  ASSERT_TRUE(r.usable) << r.brief;
  EXPECT_EQ(r.colmap_version.rfind("COLMAP 3.", 0), 0u) << r.colmap_version;
  // max_num_features caps the detections; each gets up to two orientations
  // (SiftExtraction.max_num_orientations = 2), each its own keypoint.
  for (int n : r.matches.num_keypoints) {
    EXPECT_GT(n, 1000);
    EXPECT_LE(n, 2 * options.max_num_features);
  }
  ASSERT_EQ(r.matches.pairs.size(), 6u);  // every pair overlaps

  std::vector<double> all_errors;
  for (const ColmapPairMatches& pair : r.matches.pairs) {
    ASSERT_LT(pair.tile_a, pair.tile_b);
    ASSERT_EQ(pair.q_a_px.cols(), pair.q_b_px.cols());
    const Eigen::Matrix2Xd predicted =
        TransferThroughTruth(truth, truth_tile[pair.tile_a], truth_tile[pair.tile_b], pair.q_a_px);
    std::vector<double> errors;
    for (Eigen::Index k = 0; k < predicted.cols(); ++k)
      errors.push_back((pair.q_b_px.col(k) - predicted.col(k)).norm());
    const double median = Median(errors);
    const double inliers =
        std::count_if(errors.begin(), errors.end(), [](double e) { return e < 1.5; }) /
        static_cast<double>(errors.size());
    std::printf("tiles %d-%d: %zu matches, median error %.3f px, %.1f %% within 1.5 px\n",
                pair.tile_a, pair.tile_b, errors.size(), median, 100 * inliers);
    // Measured on this project: 560-2248 matches per pair, median 0.13-0.15
    // px, 98-99.6 % within 1.5 px. A SIFT keypoint is a DoG extremum found to
    // ~0.1 px on textured content and not affine invariant (the two views
    // differ by the lens distortion and tilt over the field), and an error
    // is the difference of two keypoints: 0.3 px is 2x the measured median.
    // COLMAP's own verification admits up to max_error_px = 4 px, so a few
    // percent of coarse matches remain; 95 % within 1.5 px.
    EXPECT_GE(errors.size(), 200u);
    EXPECT_LT(median, 0.3);
    EXPECT_GT(inliers, 0.95);
    all_errors.insert(all_errors.end(), errors.begin(), errors.end());
  }
  std::printf("all: median error %.3f px\n", Median(all_errors));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omm
