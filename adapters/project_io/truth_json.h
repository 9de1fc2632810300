// The truth of a simulated project as JSON (format `omm-truth/1`).
//
// Layout (lengths mm, angles radians, pixels with (0, 0) at the centre of the
// top-left pixel; a pose is {"R": 3x3 rows, "t": [x, y, z], "r": angle-axis}
// and maps source coordinates to target ones, p_target = R p_source + t; "r"
// is mrcal's rotation vector of R, for convenience, and is ignored on reading):
//
// {
//   "format": "omm-truth/1", "preset": "demo", "seed": 1,
//   "camera": {"lens_model": "LENSMODEL_OPENCV8", "intrinsics": [fx, fy, cx, cy, ...],
//              "imager_size_px": [1600, 1200], "pixel_pitch_um": 4.49,
//              "focal_length_mm": 12.1, "psf_sigma_px": 0.75},
//   "board": {"type": "caltab", "rows": 7, "cols": 7, "pitch_mm": 12.5,
//             "dot_diameter_mm": 6.25, "frame_mm": 100, "frame_bar_mm": 3.125,
//             "triangle_mm": 12.5, "plate_size_mm": 120},
//   "calib_images": [{"image": "calib_00.png", "kind": "full" | "partial" | "plate-absent",
//                     "cam_from_plate": pose,
//                     "exposure": {"gain": 1.0, "vignetting": 0.15, "psf_sigma_px": 0.8}}],
//   "part": {"cam_from_part": pose, "outline_min_mm": [x, y], "outline_max_mm": [x, y],
//            "thickness_mm": 12},
//   "table": {"sigma_mm": 0.02,
//             "tiles": [{"image": "tile_r0c0.png", "grid": [row, col],
//                        "commanded_mm": [x, y], "actual_mm": [x, y], "exposure": {...}}]},
//   "holes": [{"name": "hole_01", "center_mm": [x, y], "diameter_mm": 20.013,
//              "nominal_diameter_mm": 20}],
//   "markers": [{"id": 3, "corners_mm": [[x, y] x 4], "tag_size_mm": 20, "paper_size_mm": 30}],
//   "part_from_plate": pose or null,
//   "measurements": [{"name": "hole_01_to_hole_07", "value_mm": 212.3456}]
// }
// Numbers are written with round-trip precision: reading gives back the same
// doubles.
#pragma once

#include <filesystem>
#include <string>

#include "pipeline/core/truth.h"

namespace omm {

std::string TruthToJson(const SimulationTruth& truth);

// Parses TruthToJson's text. Throws InputError naming `where` and the key on
// malformed input.
SimulationTruth TruthFromJson(const std::string& text, const std::string& where);

// File versions; the write goes through a temporary file and a rename.
void WriteTruthJson(const SimulationTruth& truth, const std::filesystem::path& path);
SimulationTruth ReadTruthJson(const std::filesystem::path& path);

}  // namespace omm
