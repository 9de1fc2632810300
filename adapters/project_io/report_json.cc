#include "adapters/project_io/report_json.h"

#include <set>
#include <stdexcept>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "adapters/project_io/text_file.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

using Json = nlohmann::ordered_json;

// ------------------------------------------------------------- writing ---

Json ToJson(const ReportValue& value) {
  return std::visit(
      [](const auto& v) -> Json {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, ReportValue::Array>) {
          Json array = Json::array();
          for (const ReportValue& item : v) array.push_back(ToJson(item));
          return array;
        } else if constexpr (std::is_same_v<T, ReportValue::Object>) {
          Json object = Json::object();
          for (const auto& [key, item] : v) object[key] = ToJson(item);
          return object;
        } else {
          return Json(v);
        }
      },
      value.data());
}

Json Optional(const std::optional<double>& value) { return value ? Json(*value) : Json(nullptr); }

Json Optional(const std::optional<Eigen::Vector2d>& value) {
  return value ? Json{value->x(), value->y()} : Json(nullptr);
}

// Appends `extra` after the named fields; a name clash is a bug of the stage
// that filled `extra`.
void AppendExtra(Json& section, const ReportObject& extra, const char* section_name) {
  for (const auto& [key, value] : extra) {
    if (section.contains(key)) {
      throw std::logic_error(
          fmt::format("report: extra member '{}' of '{}' hides a named field", key, section_name));
    }
    section[key] = ToJson(value);
  }
}

// -------------------------------------------------------------- reading ---

ReportValue FromJson(const Json& json) {
  switch (json.type()) {
    case Json::value_t::boolean: return json.get<bool>();
    case Json::value_t::number_integer: return json.get<std::int64_t>();
    case Json::value_t::number_unsigned:
      return static_cast<std::int64_t>(json.get<std::uint64_t>());
    case Json::value_t::number_float: return json.get<double>();
    case Json::value_t::string: return json.get<std::string>();
    case Json::value_t::array: {
      ReportValue::Array array;
      for (const Json& item : json) array.push_back(FromJson(item));
      return array;
    }
    case Json::value_t::object: {
      ReportValue::Object object;
      for (const auto& [key, item] : json.items()) object.emplace_back(key, FromJson(item));
      return object;
    }
    default: return nullptr;
  }
}

// Typed access that names the member in errors, and collects the members it
// did not consume into `extra`.
class Section {
 public:
  Section(const Json& json, std::string path, std::string where)
      : json_(json), path_(std::move(path)), where_(std::move(where)) {
    if (!json_.is_object()) Fail("", "expected an object");
  }

  [[noreturn]] void Fail(const std::string& key, const std::string& what) const {
    const std::string name = path_.empty() ? key : key.empty() ? path_ : path_ + "." + key;
    throw InputError(where_, name.empty() ? what : fmt::format("member '{}': {}", name, what));
  }

  const Json* Find(const std::string& key) {
    used_.insert(key);
    const auto it = json_.find(key);
    return it == json_.end() || it->is_null() ? nullptr : &*it;
  }

  std::string String(const std::string& key, bool required = true) {
    const Json* value = Find(key);
    if (value == nullptr) {
      if (required) Fail(key, "missing");
      return "";
    }
    if (!value->is_string()) Fail(key, "expected text");
    return value->get<std::string>();
  }

  std::optional<double> Number(const std::string& key) {
    const Json* value = Find(key);
    if (value == nullptr) return std::nullopt;
    if (!value->is_number()) Fail(key, "expected a number");
    return value->get<double>();
  }

  double RequiredNumber(const std::string& key) {
    const auto value = Number(key);
    if (!value) Fail(key, "missing");
    return *value;
  }

  int Int(const std::string& key) {
    const Json* value = Find(key);
    if (value == nullptr) Fail(key, "missing");
    if (!value->is_number_integer()) Fail(key, "expected an integer");
    return value->get<int>();
  }

  // Two numbers [a, b].
  Eigen::Vector2d Pair(const std::string& key) {
    const auto pair = OptionalPair(key);
    if (!pair) Fail(key, "missing");
    return *pair;
  }

  std::optional<Eigen::Vector2d> OptionalPair(const std::string& key) {
    const Json* value = Find(key);
    if (value == nullptr) return std::nullopt;
    if (!value->is_array() || value->size() != 2 || !(*value)[0].is_number() ||
        !(*value)[1].is_number()) {
      Fail(key, "expected two numbers [a, b]");
    }
    return Eigen::Vector2d((*value)[0].get<double>(), (*value)[1].get<double>());
  }

  ReportObject Extra() const {
    ReportObject extra;
    for (const auto& [key, value] : json_.items()) {
      if (used_.count(key) == 0) extra.emplace_back(key, FromJson(value));
    }
    return extra;
  }

 private:
  const Json& json_;
  std::string path_;
  std::string where_;
  std::set<std::string> used_;
};

CalibrationReport ReadCalibration(const Json& json, const std::string& where) {
  Section section(json, "calibration", where);
  CalibrationReport calibration;
  calibration.lens_model = section.String("lens_model");
  calibration.rms_px = section.RequiredNumber("rms_px");
  calibration.images_used = section.Int("images_used");
  if (const Json* rejected = section.Find("images_rejected")) {
    if (!rejected->is_array()) section.Fail("images_rejected", "expected an array");
    for (size_t i = 0; i < rejected->size(); ++i) {
      Section item((*rejected)[i], fmt::format("calibration.images_rejected[{}]", i), where);
      calibration.images_rejected.push_back({item.String("image"), item.String("why")});
    }
  }
  calibration.extra = section.Extra();
  return calibration;
}

MosaicReport ReadMosaic(const Json& json, const std::string& where) {
  Section section(json, "mosaic", where);
  MosaicReport mosaic;
  mosaic.file = section.String("file");
  mosaic.rms_px = section.RequiredNumber("rms_px");
  mosaic.gsd_mm = section.RequiredNumber("gsd_mm");
  const Eigen::Vector2d size = section.Pair("size_px");
  mosaic.size_px = size.cast<int>();
  if (mosaic.size_px.cast<double>() != size) section.Fail("size_px", "expected two integers");
  mosaic.origin_mm = section.Pair("origin_mm");
  mosaic.extra = section.Extra();
  return mosaic;
}

FeatureReport ReadFeature(const Json& json, const std::string& path, const std::string& where) {
  Section section(json, path, where);
  FeatureReport feature;
  feature.name = section.String("name");
  const std::string type = section.String("type");
  if (type != FeatureTypeName(FeatureType::kCircle))
    section.Fail("type", fmt::format("unknown feature type '{}'", type));
  feature.centre_mm = section.OptionalPair("centre_mm");
  feature.diameter_mm = section.Number("diameter_mm");
  feature.centre_sigma_mm = section.OptionalPair("centre_sigma_mm");
  feature.diameter_sigma_mm = section.Number("diameter_sigma_mm");
  feature.error = section.String("error", /*required=*/false);
  feature.extra = section.Extra();
  return feature;
}

MeasurementReport ReadMeasurement(const Json& json, const std::string& path,
                                  const std::string& where) {
  Section section(json, path, where);
  MeasurementReport measurement;
  measurement.name = section.String("name");
  const std::string type = section.String("type");
  if (type == MeasurementTypeName(MeasurementType::kDistance)) {
    measurement.type = MeasurementType::kDistance;
  } else if (type == MeasurementTypeName(MeasurementType::kDiameter)) {
    measurement.type = MeasurementType::kDiameter;
  } else {
    section.Fail("type", fmt::format("unknown measurement type '{}'", type));
  }
  measurement.value_mm = section.Number("value_mm");
  measurement.sigma_mm = section.Number("sigma_mm");
  measurement.cmm_mm = section.Number("cmm_mm");
  measurement.cmm_sigma_mm = section.Number("cmm_sigma_mm");
  measurement.deviation_mm = section.Number("deviation_mm");
  measurement.deviation_sigma = section.Number("deviation_sigma");
  measurement.deviation_combined_sigma = section.Number("deviation_combined_sigma");
  measurement.error = section.String("error", /*required=*/false);
  measurement.extra = section.Extra();
  return measurement;
}

}  // namespace

std::string ReportToJson(const Report& report) {
  Json json = Json::object();
  json["format"] = report.format;
  json["project"] = report.project;
  json["software_version"] = report.software_version;
  json["inputs_sha256"] = report.inputs_sha256;
  if (!report.stage_inputs_sha256.empty()) json["stage_inputs_sha256"] = report.stage_inputs_sha256;
  if (report.calibration) {
    const CalibrationReport& c = *report.calibration;
    Json section = {{"lens_model", c.lens_model},
                    {"rms_px", c.rms_px},
                    {"images_used", c.images_used},
                    {"images_rejected", Json::array()}};
    for (const RejectedImage& rejected : c.images_rejected) {
      section["images_rejected"].push_back({{"image", rejected.image}, {"why", rejected.why}});
    }
    AppendExtra(section, c.extra, "calibration");
    json["calibration"] = std::move(section);
  }
  if (report.mosaic) {
    const MosaicReport& m = *report.mosaic;
    Json section = {{"file", m.file},
                    {"rms_px", m.rms_px},
                    {"gsd_mm", m.gsd_mm},
                    {"size_px", {m.size_px.x(), m.size_px.y()}},
                    {"origin_mm", {m.origin_mm.x(), m.origin_mm.y()}}};
    AppendExtra(section, m.extra, "mosaic");
    json["mosaic"] = std::move(section);
  }
  if (report.features) {
    Json list = Json::array();
    for (const FeatureReport& f : *report.features) {
      Json item = {{"name", f.name},
                   {"type", FeatureTypeName(f.type)},
                   {"centre_mm", Optional(f.centre_mm)},
                   {"diameter_mm", Optional(f.diameter_mm)},
                   {"centre_sigma_mm", Optional(f.centre_sigma_mm)},
                   {"diameter_sigma_mm", Optional(f.diameter_sigma_mm)}};
      if (!f.error.empty()) item["error"] = f.error;
      AppendExtra(item, f.extra, "features[]");
      list.push_back(std::move(item));
    }
    json["features"] = std::move(list);
  }
  if (report.measurements) {
    Json list = Json::array();
    for (const MeasurementReport& m : *report.measurements) {
      Json item = {{"name", m.name},
                   {"type", MeasurementTypeName(m.type)},
                   {"value_mm", Optional(m.value_mm)},
                   {"sigma_mm", Optional(m.sigma_mm)},
                   {"cmm_mm", Optional(m.cmm_mm)},
                   {"deviation_mm", Optional(m.deviation_mm)},
                   {"deviation_sigma", Optional(m.deviation_sigma)}};
      // Beyond the contract: only where cmm.csv states the CMM's sigma.
      if (m.cmm_sigma_mm) item["cmm_sigma_mm"] = *m.cmm_sigma_mm;
      if (m.deviation_combined_sigma)
        item["deviation_combined_sigma"] = *m.deviation_combined_sigma;
      if (!m.error.empty()) item["error"] = m.error;
      AppendExtra(item, m.extra, "measurements[]");
      list.push_back(std::move(item));
    }
    json["measurements"] = std::move(list);
  }
  AppendExtra(json, report.extra, "report");
  return json.dump(2) + "\n";
}

Report ReportFromJson(const std::string& text, const std::string& where) {
  Json json;
  try {
    json = Json::parse(text);
  } catch (const Json::parse_error& e) {
    throw InputError(where, std::string("not valid JSON: ") + e.what());
  }
  Section root(json, "", where);
  Report report;
  report.format = root.String("format");
  if (report.format != kReportFormat) {
    root.Fail("format", fmt::format("this omm reads '{}', got '{}'", kReportFormat, report.format));
  }
  report.project = root.String("project", /*required=*/false);
  report.software_version = root.String("software_version", /*required=*/false);
  report.inputs_sha256 = root.String("inputs_sha256", /*required=*/false);
  if (const Json* stages = root.Find("stage_inputs_sha256")) {
    Section section(*stages, "stage_inputs_sha256", where);
    for (const auto& [stage, hash] : stages->items()) {
      report.stage_inputs_sha256[stage] = section.String(stage);
    }
  }
  if (const Json* calibration = root.Find("calibration")) {
    report.calibration = ReadCalibration(*calibration, where);
  }
  if (const Json* mosaic = root.Find("mosaic")) report.mosaic = ReadMosaic(*mosaic, where);
  if (const Json* list = root.Find("features")) {
    if (!list->is_array()) root.Fail("features", "expected an array");
    report.features.emplace();
    for (size_t i = 0; i < list->size(); ++i) {
      report.features->push_back(ReadFeature((*list)[i], fmt::format("features[{}]", i), where));
    }
  }
  if (const Json* list = root.Find("measurements")) {
    if (!list->is_array()) root.Fail("measurements", "expected an array");
    report.measurements.emplace();
    for (size_t i = 0; i < list->size(); ++i) {
      report.measurements->push_back(
          ReadMeasurement((*list)[i], fmt::format("measurements[{}]", i), where));
    }
  }
  report.extra = root.Extra();
  return report;
}

void WriteReportJson(const std::filesystem::path& path, const Report& report) {
  WriteTextFileAtomically(path, ReportToJson(report));
}

Report ReadReportJson(const std::filesystem::path& path) {
  return ReportFromJson(ReadTextFile(path, "report not found"), path.string());
}

}  // namespace omm
