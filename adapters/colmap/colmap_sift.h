// COLMAP's SIFT as an optional feature source: the installed `colmap` program
// (Debian's 3.8, CPU, headless) extracts and matches SIFT features on the
// tiles, and its database gives back, per pair of tiles, the geometrically
// verified matches as pixel pairs.
//
// Runs, in a private temporary directory holding symlinks to the tiles
// (named tile_<index><ext>, so names map back to tile indices whatever the
// original names are):
//   colmap feature_extractor --database_path DB --image_path DIR
//       --ImageReader.single_camera 1 --SiftExtraction.use_gpu 0 ...
//   colmap exhaustive_matcher --database_path DB --SiftMatching.use_gpu 0 ...
// or, for the given pairs of tiles only (those the table prior makes
// overlap: the others cannot match; on the demo 20 pairs of 36, matched in
// 4.8 s instead of 10.4 s),
//   colmap matches_importer --database_path DB --match_list_path PAIRS
//       --match_type pairs --SiftMatching.use_gpu 0 ...
// with QT_QPA_PLATFORM=offscreen, their output captured in colmap.log, then
// reads the database (https://colmap.github.io/database.html):
// - images (image_id, name);
// - keypoints (image_id, rows, cols, data): rows x cols float32, row-major;
//   cols = 6 (x, y, a11, a12, a21, a22: COLMAP 3.8), 4 (x, y, scale,
//   orientation) or 2 (x, y); only x, y are used;
// - two_view_geometries (pair_id, rows, cols = 2, data): rows x 2 uint32
//   keypoint indices (into image_id1's, image_id2's keypoints), the inliers of
//   the pair's verified two-view model; pair_id = image_id1 * 2147483647 +
//   image_id2 with image_id1 < image_id2.
//
// COLMAP reads a 16-bit sample as its high byte, which leaves samples of
// fewer bits stored unshifted (a 12-bit camera's, at most 15 of 255) almost
// black: no keypoints. With sample_bits < 16, 16-bit tiles are given to it as
// 8-bit copies over their own full scale (2^sample_bits - 1) instead.
//
// Pixels: COLMAP puts (0, 0) at the corner of the top-left pixel, omm at its
// centre (pipeline/README.md): every keypoint gets - 0.5 here.
#pragma once

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

namespace omm {

struct ColmapSiftOptions {
  std::string binary = "colmap";  // the program: a name looked up in PATH, or a path
  // Detections per image (SiftExtraction.max_num_features); each detection
  // gives up to two keypoints (two dominant orientations), so up to 2x this.
  // Half COLMAP's 8192: on the demo's tiles the registration is the same
  // (holes 0.0267 vs 0.0266 raw px RMS, matches 0.024 px), the exhaustive
  // matching 5x faster (27 s vs 133 s on 2 cores).
  int max_num_features = 4000;
  // The scale space's first octave (SiftExtraction.first_octave). COLMAP's
  // default, -1, doubles the image first, for keypoints finer than a pixel;
  // here keypoints only anchor template matches (register_tiles.h), which
  // locate them. On the demo's tiles 0 gives as many keypoints and the same
  // registration (holes 0.0268 raw px RMS either way, matches 0.0250 vs
  // 0.0249 px), its extraction 3x faster (omm_colmap_sift_benchmark on 2
  // cores: 7.5 s vs 23.0 s; 55.5k vs 55.0k keypoints, 28.4k vs 28.3k
  // verified matches).
  int first_octave = 0;
  int num_threads = 2;  // extraction and matching threads
  // The verification RANSAC's inlier distance (SiftMatching.max_error), px.
  double max_error_px = 4.0;
  // A pair with fewer verified inliers gets no matches (SiftMatching.min_num_inliers).
  int min_num_inliers = 15;
  double timeout_seconds = 600.0;  // per colmap command; killed after that, a failure
  // The bits the tiles' samples use (Project::sample_bits), 8 to 16.
  int sample_bits = 16;
  // Keep the temporary directory (database, colmap.log) and report its path.
  bool keep_work_dir = false;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// The verified matches between two tiles, omm pixels.
struct ColmapPairMatches {
  int tile_a = 0, tile_b = 0;  // tile_a < tile_b
  Eigen::Matrix2Xd q_a_px;     // column k: match k's keypoint in tile a
  Eigen::Matrix2Xd q_b_px;     // ... and in tile b
};

// A COLMAP database's keypoints and verified matches, by tile.
struct ColmapDatabaseMatches {
  std::vector<int> num_keypoints;        // per tile; 0 for a tile not in the database
  std::vector<ColmapPairMatches> pairs;  // pairs with >= 1 match, by (tile_a, tile_b)
  int num_matches = 0;                   // over all pairs
};

// Reads `database_path`. image_names[i]: the database's image name of tile i;
// images with other names are ignored. Throws InputError naming the file if
// it cannot be opened, lacks a table, or holds a blob that does not fit its
// rows and cols, a keypoint index out of range or an unsupported cols.
ColmapDatabaseMatches ReadColmapDatabaseMatches(const std::filesystem::path& database_path,
                                                const std::vector<std::string>& image_names);

struct ColmapSiftResult {
  bool usable = false;         // false: colmap missing, failed or timed out (brief says which)
  std::string brief;           // one line: version, keypoints, pairs, matches, time, or the failure
  std::string colmap_version;  // first line of `colmap -h`'s banner, e.g. "COLMAP 3.8"
  ColmapDatabaseMatches matches;
  double extraction_seconds = 0.0, matching_seconds = 0.0, reading_seconds = 0.0;
  std::filesystem::path work_dir;  // only with keep_work_dir
};

// Runs colmap on `tile_paths` (tile i = tile_paths[i]) as described above,
// matching the tile index pairs `pairs` (either order), or every pair if it
// is empty. Throws InputError for invalid options, a pair that is not two of
// the tiles, or a tile file that does not exist; a missing binary, a failing
// or timed-out colmap or an unreadable database come back as usable = false
// with the reason (and the log's last line) in brief.
ColmapSiftResult ColmapSiftMatches(const std::vector<std::filesystem::path>& tile_paths,
                                   const ColmapSiftOptions& options,
                                   const std::vector<std::pair<int, int>>& pairs = {});

}  // namespace omm
