// out/report.html: the report for a person, one self-contained file. Inline
// CSS and SVG, the mosaic as a data: URI PNG; no scripts, no external URLs,
// so it opens anywhere and can be archived or mailed alone.
//
// Sections, each replaced by a line saying so when its stage has not run or
// a file it needs is missing:
//  - header: project, omm version, SHA-256 of the inputs, and the report's
//    other top-level members (e.g. the date of the run);
//  - measurements: value, 1-sigma, CMM value, deviation in mm and in sigma
//    (highlighted beyond 3 sigma), sigma by source, why a failed one failed;
//    the located features;
//  - the mosaic, downsampled, with every located feature (its circle, name)
//    and every distance (a line between the centres, name and value) drawn
//    over it, the labels placed so that none covers another (label_layout.h);
//  - calibration: lens model and why, rms, images used and rejected (why),
//    residuals per image, the residual, uncertainty-map and study plots;
//  - mosaic: rms, per-pair matches, per-tile adjusted-minus-commanded table
//    positions, tiles held by the prior (why), exposure compensation.
// Every text taken from the report or project is HTML-escaped: names come
// from user files.
//
// Overlay geometry: the overlay's SVG user space is the mosaic's pixel grid
// with (0, 0) at the outer corner of pixel (0, 0), so the centre of pixel
// (col, row) is at (col + 0.5, row + 0.5) and, by the pixel convention of
// project-format.md (centre of (col, row) at part-frame (origin_x + (col +
// 0.5) gsd, origin_y - (row + 0.5) gsd)), the part-frame point (x, y) mm is at
//   ((x - origin_x) / gsd, (origin_y - y) / gsd).
// The preview PNG is stretched over the whole grid, whatever its own size.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/core/image.h"
#include "pipeline/core/project.h"
#include "pipeline/core/report.h"

namespace omm {

struct ReportHtmlOptions {
  // Width of the embedded mosaic preview, px (area-averaged down; a narrower
  // mosaic is embedded as it is).
  int mosaic_preview_width_px = 1200;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

// What the page shows besides the report itself.
struct ReportHtmlInputs {
  std::string mosaic_png;  // PNG file bytes of the mosaic preview; empty: none
  // Why there is no preview although the report has a mosaic section.
  std::string mosaic_missing_why;
  // The calibration's plots (SVG documents); empty: absent.
  std::string residuals_svg;
  std::string uncertainty_svg;
  std::string study_svg;
  // project.yaml's measurements: the features a distance joins (the report
  // names only the measurement). Without them no distance line is drawn.
  std::vector<MeasurementSpec> measurements;
};

// The page. Pure: no files.
std::string ReportHtml(const Report& report, const ReportHtmlInputs& inputs);

// The inputs from the files the report names (report.mosaic.file, the
// calibration extra's "residuals_plot", "uncertainty_plot", "study"."plot"),
// each taken from the first of `dirs` that holds it (a run's staging
// directory, then out/). A missing or unreadable file is left out, its
// section saying so; never an error. `mosaic`, if given, is report.mosaic's
// image already in memory: its file is then not read.
ReportHtmlInputs ReadReportHtmlInputs(const Report& report,
                                      const std::vector<std::filesystem::path>& dirs,
                                      const std::vector<MeasurementSpec>& measurements,
                                      const ReportHtmlOptions& options,
                                      const StoredImage* mosaic = nullptr);

// ReportHtml(report, ReadReportHtmlInputs(...)) written to `path` through a
// temporary file and a rename (a reader sees the old page or the new one).
// Throws InputError if it cannot be written, std::invalid_argument for
// invalid options.
void WriteReportHtml(const std::filesystem::path& path, const Report& report,
                     const std::vector<std::filesystem::path>& dirs,
                     const std::vector<MeasurementSpec>& measurements,
                     const ReportHtmlOptions& options = {}, const StoredImage* mosaic = nullptr);

}  // namespace omm
