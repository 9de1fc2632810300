// The identity of a project's inputs, for the report and for deciding whether
// a report is current.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "pipeline/core/project.h"
#include "pipeline/orchestration/stage.h"

namespace omm {

// The files a run depends on, in a fixed order: project.yaml, table.csv and
// cmm.csv (if present), the calib/ images, the tiles, and the reused
// calibration (the .cameramodel of `calibration.from`, or out/camera.cameramodel
// of the project it names, if present).
std::vector<std::filesystem::path> ProjectInputFiles(const Project& project);

// SHA-256 over, for each input file in order: its path relative to the project
// directory (as text), a NUL byte, and the SHA-256 of its bytes. Renaming,
// editing, adding or removing any input changes it. An image's hash is the
// one LoadProject took of the bytes it decoded (Project::images), if loaded.
// Throws InputError if a file cannot be read.
std::string HashProjectInputs(const Project& project);

// SHA-256 of a file's bytes, 64 hex digits.
std::string HashFile(const std::filesystem::path& path);

// What each stage's results depend on, one SHA-256 per stage, chained: each
// covers the stages before it too, so whatever makes a stage's results stale
// makes the later stages' stale. A stage's own inputs:
//   calibrate  calib/, the reused calibration (calibration.from's file),
//              project.yaml's format, camera, calibration and board, and the
//              images' sample bits (Project::sample_bits: the tiles count);
//   mosaic     tiles/, table.csv, project.yaml's table, mosaic and features
//              (the holes seen by two tiles tie them), the feature source;
//   measure    project.yaml's measurements, cmm.csv.
// project.yaml counts by its sections' content (Project::yaml_sections):
// a new measurement, a CMM value or an edited comment leaves the calibration
// and the mosaic current. Its `name` only labels the report.
struct StageInputHashes {
  std::string calibrate, mosaic, measure;
  const std::string& Of(Stage stage) const;
};
StageInputHashes HashStageInputs(const Project& project, FeatureSource mosaic_features);

// The stage of whose inputs project.yaml's top-level `key` is part;
// nullopt for `name` and for a key no stage reads.
std::optional<Stage> StageReadingYamlKey(const std::string& key);

}  // namespace omm
