// The calibration solve record as JSON, so a run can save it in out/ and a
// later run can recompute residuals and uncertainty without the images.
//
// {"format": "omm-solve-record", "version": 1,
//  "board": {"type": "caltab", "rows": 7, "cols": 7, "pitch_mm": 12.5, ...},
//  "camera": {"lens_model": "...", "intrinsics": [...], "width_px": W, "height_px": H},
//  "calobject_warp": [x2, y2],
//  "problem": {"optimize_intrinsics_core": true, ...},
//  "images": [{"image": "calib_00.png", "q_px": [[x, y], ...], "weight": [...],
//              "outlier": [false, ...], "rt_cam_from_plate": [r0, r1, r2, t0, t1, t2]}]}
// Doubles are written with round-trip precision: read(write(r)) == r exactly.
#pragma once

#include <filesystem>
#include <string>

#include "pipeline/core/calibration_result.h"

namespace omm {

std::string SolveRecordToJson(const SolveRecord& record);

// `where` names the source in errors. Throws InputError on malformed input
// (naming the key and what was expected).
SolveRecord SolveRecordFromJson(const std::string& text, const std::string& where);

void WriteSolveRecord(const std::filesystem::path& path, const SolveRecord& record);
SolveRecord ReadSolveRecord(const std::filesystem::path& path);

}  // namespace omm
