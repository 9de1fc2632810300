// What a run found, as written to out/report.json (format omm-report/1,
// ../../../shared/docs/project-format.md). Plain values: the JSON lives in
// adapters/project_io/report_json.h.
//
// Sections are optional until the stage that fills them has run. Every
// section has an `extra` object for what later stages add (per-image
// residuals, sigma breakdowns, ...): its members are written after the
// section's named fields and read back unchanged, so a reader that does not
// know them keeps them.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <variant>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/project.h"

namespace omm {

inline constexpr const char* kReportFormat = "omm-report/1";

// A JSON-like value: null, bool, integer, number, text, array or object
// (members in insertion order).
class ReportValue {
 public:
  using Array = std::vector<ReportValue>;
  using Object = std::vector<std::pair<std::string, ReportValue>>;
  using Data = std::variant<std::nullptr_t, bool, std::int64_t, double, std::string, Array, Object>;

  ReportValue() : data_(nullptr) {}
  ReportValue(std::nullptr_t) : data_(nullptr) {}                      // NOLINT: implicit by design
  ReportValue(bool value) : data_(value) {}                            // NOLINT
  ReportValue(int value) : data_(static_cast<std::int64_t>(value)) {}  // NOLINT
  ReportValue(std::int64_t value) : data_(value) {}                    // NOLINT
  ReportValue(double value) : data_(value) {}                          // NOLINT
  ReportValue(std::string value) : data_(std::move(value)) {}          // NOLINT
  ReportValue(const char* value) : data_(std::string(value)) {}        // NOLINT
  ReportValue(Array value) : data_(std::move(value)) {}                // NOLINT
  ReportValue(Object value) : data_(std::move(value)) {}               // NOLINT

  const Data& data() const { return data_; }
  bool operator==(const ReportValue& other) const { return data_ == other.data_; }

 private:
  Data data_;
};

using ReportObject = ReportValue::Object;

// Reading an `extra` object: each accessor is null (nullopt) when the member
// is absent or of another kind, so readers of older or newer reports degrade.
inline const ReportValue* Member(const ReportObject& object, std::string_view key) {
  for (const auto& [name, value] : object)
    if (name == key) return &value;
  return nullptr;
}

// A number (JSON numbers without a fraction come back as integers).
inline std::optional<double> AsNumber(const ReportValue* value) {
  if (value == nullptr) return std::nullopt;
  if (const auto* i = std::get_if<std::int64_t>(&value->data())) return static_cast<double>(*i);
  if (const auto* d = std::get_if<double>(&value->data())) return *d;
  return std::nullopt;
}

inline std::optional<bool> AsBool(const ReportValue* value) {
  if (value == nullptr) return std::nullopt;
  if (const auto* b = std::get_if<bool>(&value->data())) return *b;
  return std::nullopt;
}

inline const std::string* AsString(const ReportValue* value) {
  return value == nullptr ? nullptr : std::get_if<std::string>(&value->data());
}

inline const ReportValue::Array* AsArray(const ReportValue* value) {
  return value == nullptr ? nullptr : std::get_if<ReportValue::Array>(&value->data());
}

// An array of two numbers ([x, y]).
inline std::optional<Eigen::Vector2d> AsPair(const ReportValue* value) {
  const ReportValue::Array* array = AsArray(value);
  if (array == nullptr || array->size() != 2) return std::nullopt;
  const std::optional<double> x = AsNumber(&(*array)[0]), y = AsNumber(&(*array)[1]);
  if (!x || !y) return std::nullopt;
  return Eigen::Vector2d(*x, *y);
}

inline const ReportObject* AsObject(const ReportValue* value) {
  return value == nullptr ? nullptr : std::get_if<ReportObject>(&value->data());
}

struct RejectedImage {
  std::string image;  // file name in calib/
  std::string why;    // "plate not found", ...
};

struct CalibrationReport {
  std::string lens_model;  // the mrcal lens model used
  double rms_px = 0.0;     // RMS reprojection residual of the inliers
  int images_used = 0;
  std::vector<RejectedImage> images_rejected;
  ReportObject extra;
};

struct MosaicReport {
  std::string file;                                   // e.g. "mosaic.tif", relative to out/
  double rms_px = 0.0;                                // RMS reprojection residual of the adjustment
  double gsd_mm = 0.0;                                // mosaic pixel size
  Eigen::Vector2i size_px = Eigen::Vector2i::Zero();  // width, height
  Eigen::Vector2d origin_mm = Eigen::Vector2d::Zero();  // part-frame outer corner of pixel (0, 0)
  ReportObject extra;
};

struct MeasurementReport {
  std::string name;
  MeasurementType type = MeasurementType::kDistance;
  std::optional<double> value_mm;      // absent when it could not be made (then `error` says why)
  std::optional<double> sigma_mm;      // 1-sigma standard uncertainty of value_mm
  std::optional<double> cmm_mm;        // reference value from cmm.csv
  std::optional<double> cmm_sigma_mm;  // its 1-sigma, where cmm.csv states it
  std::optional<double> deviation_mm;  // value_mm - cmm_mm
  std::optional<double> deviation_sigma;  // deviation_mm / sigma_mm
  // deviation_mm / sqrt(sigma_mm^2 + cmm_sigma_mm^2), where the CMM's sigma
  // is stated: the deviation against both values' uncertainties (ISO
  // 13528's zeta score).
  std::optional<double> deviation_combined_sigma;
  std::string error;  // empty when value_mm is set
  ReportObject extra;
};

// The deviation in the sigmas it is judged by (the 3-sigma flag, the CMM
// agreement of a batch): against both uncertainties where the CMM's is
// stated, else against the measurement's.
inline std::optional<double> JudgedDeviationSigma(const MeasurementReport& m) {
  return m.deviation_combined_sigma ? m.deviation_combined_sigma : m.deviation_sigma;
}

// A located feature (a circle of project.yaml's `features`), part frame, mm.
struct FeatureReport {
  std::string name;
  FeatureType type = FeatureType::kCircle;
  std::optional<Eigen::Vector2d> centre_mm;  // absent when not found (then `error` says why)
  std::optional<double> diameter_mm;
  // 1-sigma of centre x, y and of the diameter, every modelled source.
  std::optional<Eigen::Vector2d> centre_sigma_mm;
  std::optional<double> diameter_sigma_mm;
  std::string error;  // empty when found
  ReportObject extra;
};

struct Report {
  std::string format = kReportFormat;
  std::string project;           // project name
  std::string software_version;  // omm's version that wrote it
  std::string inputs_sha256;     // hash of the project's input files (see orchestration)
  // Per stage whose section is present ("calibrate", "mosaic", "measure"):
  // the hash of the inputs it ran on (orchestration's HashStageInputs).
  std::map<std::string, std::string> stage_inputs_sha256;
  std::optional<CalibrationReport> calibration;
  std::optional<MosaicReport> mosaic;
  std::optional<std::vector<FeatureReport>> features;
  std::optional<std::vector<MeasurementReport>> measurements;
  ReportObject extra;
};

}  // namespace omm
