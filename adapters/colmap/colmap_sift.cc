#include "adapters/colmap/colmap_sift.h"

#include <sqlite3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <tuple>

#include "adapters/opencv/image_io.h"
#include "adapters/process/process.h"
#include "pipeline/core/error.h"
#include "pipeline/core/timing.h"

namespace omm {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// COLMAP pixel (corner of the top-left pixel at 0) -> omm's (centre at 0).
constexpr double kColmapPixelShift = 0.5;
// COLMAP's kMaxNumImages: pair_id = image_id1 * kPairIdBase + image_id2.
constexpr std::int64_t kPairIdBase = 2147483647;

std::string Fixed(double value, int digits) {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(digits);
  out << value;
  return out.str();
}

// ---------------------------------------------------------------- database

struct DbCloser {
  void operator()(sqlite3* db) const { sqlite3_close(db); }
};
struct StmtFinalizer {
  void operator()(sqlite3_stmt* stmt) const { sqlite3_finalize(stmt); }
};
using Db = std::unique_ptr<sqlite3, DbCloser>;
using Stmt = std::unique_ptr<sqlite3_stmt, StmtFinalizer>;

Stmt Prepare(sqlite3* db, const std::string& sql, const std::string& where) {
  sqlite3_stmt* stmt = nullptr;
  if (sqlite3_prepare_v2(db, sql.c_str(), -1, &stmt, nullptr) != SQLITE_OK)
    throw InputError(
        where, "not a COLMAP database (" + std::string(sqlite3_errmsg(db)) + " in '" + sql + "')");
  return Stmt(stmt);
}

// Steps `stmt` to its next row; false at the end. Throws on an error.
bool Step(sqlite3* db, sqlite3_stmt* stmt, const std::string& where) {
  const int rc = sqlite3_step(stmt);
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  throw InputError(where, std::string("reading failed: ") + sqlite3_errmsg(db));
}

// Column `col` as a blob of rows x cols elements of 4 bytes (float32 or
// uint32), copied into `out` (an empty blob is fine for rows = 0).
template <typename T>
void ReadBlob(sqlite3_stmt* stmt, int col, std::int64_t rows, std::int64_t cols,
              const std::string& what, const std::string& where, std::vector<T>* out) {
  static_assert(sizeof(T) == 4);
  const void* data = sqlite3_column_blob(stmt, col);
  const std::int64_t bytes = sqlite3_column_bytes(stmt, col);
  if (rows < 0 || cols < 0 || bytes != rows * cols * 4)
    throw InputError(where, what + ": a blob of " + std::to_string(bytes) + " bytes for " +
                                std::to_string(rows) + " x " + std::to_string(cols) +
                                " 4-byte values");
  out->resize(static_cast<size_t>(rows * cols));
  if (bytes > 0) std::memcpy(out->data(), data, static_cast<size_t>(bytes));
}

// ---------------------------------------------------------------- process

struct RunOutcome {
  bool ok = false;
  std::string failure;  // when not ok: what happened
};

// Runs argv (argv[0] looked up in PATH) with QT_QPA_PLATFORM=offscreen in its
// own process group, stdout and stderr appended to `log`; kills the group
// after `timeout_seconds`.
RunOutcome RunColmap(const std::vector<std::string>& argv, const fs::path& log,
                     double timeout_seconds) {
  ProcessOptions options;
  options.log_path = log;
  options.stdout_to_log = true;
  options.append_to_log = true;
  options.search_path = true;
  options.own_process_group = true;
  options.environment = {"QT_QPA_PLATFORM=offscreen"};
  RunOutcome outcome;
  try {
    const ProcessEnd end = WaitForProcess(StartProcess(argv, options), timeout_seconds);
    outcome.ok = end.Succeeded();
    if (!outcome.ok) outcome.failure = DescribeProcessEnd(end);
  } catch (const ProcessStartError& e) {
    outcome.failure =
        "cannot run '" + argv[0] + "': " + e.code().message() +
        (e.code() == std::errc::no_such_file_or_directory ? " (is the colmap package installed?)"
                                                          : "");
  }
  return outcome;
}

std::vector<std::string> ReadLines(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") != std::string::npos) lines.push_back(line);
  }
  return lines;
}

std::string LastLine(const fs::path& path) {
  const std::vector<std::string> lines = ReadLines(path);
  return lines.empty() ? "(no output)" : lines.back();
}

// A 16-bit image of `sample_bits`-bit samples as 8 bits over their full scale.
StoredImage EightBitCopy(const StoredImage& image, int sample_bits) {
  StoredImage copy{image.width, image.height, 8, {}};
  const size_t num_samples = image.samples.size() / 2;
  copy.samples.resize(num_samples);
  const double scale = 255.0 / ((1 << sample_bits) - 1);
  for (size_t i = 0; i < num_samples; ++i) {
    std::uint16_t sample;
    std::memcpy(&sample, image.samples.data() + 2 * i, 2);
    copy.samples[i] = static_cast<std::uint8_t>(std::min(255.0, std::round(sample * scale)));
  }
  return copy;
}

}  // namespace

std::string ColmapSiftOptions::Check() const {
  if (binary.empty()) return "binary is empty";
  if (max_num_features < 1) return "max_num_features must be >= 1";
  if (first_octave < -1) return "first_octave must be >= -1";
  if (num_threads < 1) return "num_threads must be >= 1";
  if (!(max_error_px > 0.0)) return "max_error_px must be > 0";
  if (min_num_inliers < 1) return "min_num_inliers must be >= 1";
  if (!(timeout_seconds > 0.0)) return "timeout_seconds must be > 0";
  if (sample_bits < 8 || sample_bits > 16) return "sample_bits must be in [8, 16]";
  return "";
}

ColmapDatabaseMatches ReadColmapDatabaseMatches(const fs::path& database_path,
                                                const std::vector<std::string>& image_names) {
  const std::string where = database_path.string();
  if (!fs::is_regular_file(database_path)) throw InputError(where, "no such database file");
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(where.c_str(), &raw, SQLITE_OPEN_READONLY, nullptr);
  const Db db(raw);
  if (rc != SQLITE_OK)
    throw InputError(where, std::string("cannot open: ") + sqlite3_errmsg(db.get()));

  std::map<std::string, int> tile_of_name;
  for (size_t i = 0; i < image_names.size(); ++i)
    tile_of_name[image_names[i]] = static_cast<int>(i);
  std::map<std::int64_t, int> tile_of_image;
  {
    const Stmt stmt = Prepare(db.get(), "SELECT image_id, name FROM images", where);
    while (Step(db.get(), stmt.get(), where)) {
      const unsigned char* name = sqlite3_column_text(stmt.get(), 1);
      const auto it = tile_of_name.find(name ? reinterpret_cast<const char*>(name) : "");
      if (it != tile_of_name.end()) tile_of_image[sqlite3_column_int64(stmt.get(), 0)] = it->second;
    }
  }

  ColmapDatabaseMatches result;
  result.num_keypoints.assign(image_names.size(), 0);
  std::vector<Eigen::Matrix2Xd> keypoints_px(image_names.size());
  {
    const Stmt stmt = Prepare(db.get(), "SELECT image_id, rows, cols, data FROM keypoints", where);
    std::vector<float> data;
    while (Step(db.get(), stmt.get(), where)) {
      const auto it = tile_of_image.find(sqlite3_column_int64(stmt.get(), 0));
      if (it == tile_of_image.end()) continue;
      const std::int64_t rows = sqlite3_column_int64(stmt.get(), 1);
      const std::int64_t cols = sqlite3_column_int64(stmt.get(), 2);
      const std::string what = "keypoints of image '" + image_names[it->second] + "'";
      if (cols != 2 && cols != 4 && cols != 6)
        throw InputError(where, what + ": cols " + std::to_string(cols) + ", expected 2, 4 or 6");
      ReadBlob(stmt.get(), 3, rows, cols, what, where, &data);
      Eigen::Matrix2Xd& q = keypoints_px[it->second];
      q.resize(2, rows);
      for (std::int64_t k = 0; k < rows; ++k) {
        q(0, k) = data[k * cols] - kColmapPixelShift;
        q(1, k) = data[k * cols + 1] - kColmapPixelShift;
      }
      result.num_keypoints[it->second] = static_cast<int>(rows);
    }
  }
  {
    const Stmt stmt =
        Prepare(db.get(), "SELECT pair_id, rows, cols, data FROM two_view_geometries", where);
    std::vector<std::uint32_t> data;
    while (Step(db.get(), stmt.get(), where)) {
      const std::int64_t pair_id = sqlite3_column_int64(stmt.get(), 0);
      const std::int64_t image_id2 = pair_id % kPairIdBase;
      const std::int64_t image_id1 = (pair_id - image_id2) / kPairIdBase;
      const auto it1 = tile_of_image.find(image_id1), it2 = tile_of_image.find(image_id2);
      if (it1 == tile_of_image.end() || it2 == tile_of_image.end()) continue;
      const std::int64_t rows = sqlite3_column_int64(stmt.get(), 1);
      if (rows == 0) continue;
      const std::int64_t cols = sqlite3_column_int64(stmt.get(), 2);
      const std::string what = "two_view_geometries of pair " + std::to_string(pair_id);
      if (cols != 2)
        throw InputError(where, what + ": cols " + std::to_string(cols) + ", expected 2");
      ReadBlob(stmt.get(), 3, rows, cols, what, where, &data);
      const bool swap = it1->second > it2->second;
      ColmapPairMatches pair;
      pair.tile_a = swap ? it2->second : it1->second;
      pair.tile_b = swap ? it1->second : it2->second;
      const Eigen::Matrix2Xd& q1 = keypoints_px[it1->second];
      const Eigen::Matrix2Xd& q2 = keypoints_px[it2->second];
      Eigen::Matrix2Xd& q_1 = swap ? pair.q_b_px : pair.q_a_px;
      Eigen::Matrix2Xd& q_2 = swap ? pair.q_a_px : pair.q_b_px;
      q_1.resize(2, rows);
      q_2.resize(2, rows);
      for (std::int64_t k = 0; k < rows; ++k) {
        const std::uint32_t i1 = data[2 * k], i2 = data[2 * k + 1];
        if (i1 >= q1.cols() || i2 >= q2.cols())
          throw InputError(
              where, what + ": match " + std::to_string(k) + " names a keypoint out of range");
        q_1.col(k) = q1.col(i1);
        q_2.col(k) = q2.col(i2);
      }
      result.num_matches += static_cast<int>(rows);
      result.pairs.push_back(std::move(pair));
    }
  }
  std::sort(result.pairs.begin(), result.pairs.end(),
            [](const ColmapPairMatches& a, const ColmapPairMatches& b) {
              return std::tie(a.tile_a, a.tile_b) < std::tie(b.tile_a, b.tile_b);
            });
  return result;
}

ColmapSiftResult ColmapSiftMatches(const std::vector<fs::path>& tile_paths,
                                   const ColmapSiftOptions& options,
                                   const std::vector<std::pair<int, int>>& pairs) {
  if (const std::string problem = options.Check(); !problem.empty())
    throw InputError("colmap sift options", problem);
  if (tile_paths.size() < 2) throw InputError("colmap sift", "needs at least two tiles");
  const int num_tiles = static_cast<int>(tile_paths.size());
  for (const auto& [a, b] : pairs) {
    if (a < 0 || b < 0 || a >= num_tiles || b >= num_tiles || a == b)
      throw InputError("colmap sift", "pair (" + std::to_string(a) + ", " + std::to_string(b) +
                                          ") is not two of the " + std::to_string(num_tiles) +
                                          " tiles");
  }
  for (const fs::path& path : tile_paths) {
    if (!fs::is_regular_file(path)) throw InputError(path.string(), "no such tile image");
  }

  ColmapSiftResult result;
  ScratchDir scratch("omm_colmap_sift_");
  if (options.keep_work_dir) {
    scratch.Keep();
    result.work_dir = scratch.path();
  }
  const fs::path& work_dir = scratch.path();
  const fs::path image_dir = work_dir / "images", database = work_dir / "database.db",
                 log = work_dir / "colmap.log";
  fs::create_directory(image_dir);
  std::vector<std::string> names;
  for (size_t i = 0; i < tile_paths.size(); ++i) {
    const std::string name = "tile_" + std::to_string(i);
    if (options.sample_bits < 16) {
      const StoredImage tile = ReadStoredImage(tile_paths[i]);
      if (tile.bit_depth == 16) {
        names.push_back(name + ".png");
        WriteStoredImage(image_dir / names.back(), EightBitCopy(tile, options.sample_bits),
                         /*png_deflate_level=*/0);
        continue;
      }
    }
    names.push_back(name + tile_paths[i].extension().string());
    fs::create_symlink(fs::absolute(tile_paths[i]), image_dir / names.back());
  }

  auto fail = [&](const std::string& step, const RunOutcome& outcome) {
    result.brief = "colmap sift: " + step + " failed: " + outcome.failure;
    if (fs::exists(log)) result.brief += "; log: " + LastLine(log);
    return result;
  };

  // The banner's first line, e.g. "COLMAP 3.8 -- Structure-from-Motion and Multi-View Stereo".
  const fs::path version_log = work_dir / "version.log";
  const RunOutcome version =
      RunColmap({options.binary, "-h"}, version_log, options.timeout_seconds);
  if (!version.ok) return fail("'" + options.binary + " -h'", version);
  const std::vector<std::string> banner = ReadLines(version_log);
  result.colmap_version =
      banner.empty() ? "" : banner.front().substr(0, banner.front().find(" --"));

  const std::string threads = std::to_string(options.num_threads);
  Clock::time_point start = Clock::now();
  const RunOutcome extraction =
      RunColmap({options.binary, "feature_extractor", "--database_path", database.string(),
                 "--image_path", image_dir.string(), "--ImageReader.single_camera", "1",
                 "--SiftExtraction.use_gpu", "0", "--SiftExtraction.num_threads", threads,
                 "--SiftExtraction.max_num_features", std::to_string(options.max_num_features),
                 "--SiftExtraction.first_octave", std::to_string(options.first_octave)},
                log, options.timeout_seconds);
  result.extraction_seconds = SecondsSince(start);
  if (!extraction.ok) return fail("feature_extractor", extraction);

  start = Clock::now();
  std::vector<std::string> matcher = {options.binary};
  if (pairs.empty()) {
    matcher.insert(matcher.end(), {"exhaustive_matcher", "--database_path", database.string()});
  } else {
    const fs::path list = work_dir / "pairs.txt";
    {
      std::ofstream out(list);
      for (const auto& [a, b] : pairs) out << names[a] << ' ' << names[b] << '\n';
    }
    matcher.insert(matcher.end(), {"matches_importer", "--database_path", database.string(),
                                   "--match_list_path", list.string(), "--match_type", "pairs"});
  }
  matcher.insert(matcher.end(),
                 {"--SiftMatching.use_gpu", "0", "--SiftMatching.num_threads", threads,
                  "--SiftMatching.max_error", std::to_string(options.max_error_px),
                  "--SiftMatching.min_num_inliers", std::to_string(options.min_num_inliers)});
  const RunOutcome matching = RunColmap(matcher, log, options.timeout_seconds);
  result.matching_seconds = SecondsSince(start);
  if (!matching.ok) return fail(matcher[1], matching);

  start = Clock::now();
  try {
    result.matches = ReadColmapDatabaseMatches(database, names);
  } catch (const InputError& error) {
    result.brief = std::string("colmap sift: reading the database failed: ") + error.what();
    return result;
  }
  result.reading_seconds = SecondsSince(start);

  int min_keypoints = result.matches.num_keypoints.front();
  for (int n : result.matches.num_keypoints) min_keypoints = std::min(min_keypoints, n);
  result.usable = true;
  result.brief = result.colmap_version + " SIFT: " + std::to_string(tile_paths.size()) +
                 " tiles, >= " + std::to_string(min_keypoints) + " keypoints each, " +
                 std::to_string(result.matches.pairs.size()) + " pairs with " +
                 std::to_string(result.matches.num_matches) + " verified matches; " +
                 Fixed(result.extraction_seconds, 1) + " s extraction, " +
                 Fixed(result.matching_seconds, 1) + " s matching";
  return result;
}

}  // namespace omm
