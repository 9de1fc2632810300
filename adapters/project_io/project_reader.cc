#include "adapters/project_io/project_reader.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <system_error>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "adapters/mrcal/lens.h"
#include "adapters/opencv/image_io.h"
#include "adapters/openssl/sha256.h"
#include "adapters/project_io/text_file.h"
#include "pipeline/core/error.h"
#include "pipeline/core/parallel_for.h"

namespace fs = std::filesystem;

namespace omm {
namespace {

constexpr const char* kProjectFormat = "omm-project/1";

// ---------------------------------------------------------------- helpers --

int EditDistance(const std::string& a, const std::string& b) {
  std::vector<int> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = static_cast<int>(j);
  for (size_t i = 1; i <= a.size(); ++i) {
    int diagonal = row[0];
    row[0] = static_cast<int>(i);
    for (size_t j = 1; j <= b.size(); ++j) {
      const int above = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = above;
    }
  }
  return row[b.size()];
}

// " (did you mean 'x'?)" when some candidate is close to `name`, else "".
std::string Suggest(const std::string& name, const std::vector<std::string>& candidates) {
  const std::string* best = nullptr;
  int best_distance = 0;
  for (const std::string& candidate : candidates) {
    const int distance = EditDistance(name, candidate);
    if (best == nullptr || distance < best_distance) {
      best = &candidate;
      best_distance = distance;
    }
  }
  const int tolerance = std::max<int>(2, static_cast<int>(name.size()) / 3);
  if (best == nullptr || best_distance > tolerance) return "";
  return fmt::format(" (did you mean '{}'?)", *best);
}

std::string Join(const std::vector<std::string>& items) {
  std::string joined;
  for (const std::string& item : items) joined += (joined.empty() ? "" : ", ") + item;
  return joined;
}

std::string Trim(std::string_view text) {
  const auto begin = text.find_first_not_of(" \t\r");
  if (begin == std::string_view::npos) return "";
  const auto end = text.find_last_not_of(" \t\r");
  return std::string(text.substr(begin, end - begin + 1));
}

// A whole field as a finite double; nothing before or after.
std::optional<double> ParseDouble(const std::string& text) {
  double value = 0.0;
  const char* begin = text.data();
  const char* end = text.data() + text.size();
  if (begin != end && *begin == '+') ++begin;
  const auto result = std::from_chars(begin, end, value);
  if (result.ec != std::errc() || result.ptr != end || !std::isfinite(value)) return std::nullopt;
  return value;
}

// A name used as a key in csv files and the report.
void CheckName(const std::string& name, const std::string& where, const std::string& what) {
  if (name.empty()) throw InputError(where, what + ": a name must not be empty");
  if (name.find_first_of(",\n\r\"") != std::string::npos || Trim(name) != name) {
    throw InputError(where, fmt::format("{} '{}': a name must not contain commas, quotes or "
                                        "line breaks, nor start or end with a space",
                                        what, name));
  }
}

// ------------------------------------------------------------ project.yaml --

// Reads typed values out of project.yaml, naming the key path and line in
// every error.
class YamlReader {
 public:
  explicit YamlReader(fs::path file) : file_(std::move(file)) {}

  [[noreturn]] void Fail(const YAML::Node& node, const std::string& key,
                         const std::string& what) const {
    std::string where = file_.string();
    if (node.IsDefined() && node.Mark().line >= 0)
      where += fmt::format(":{}", node.Mark().line + 1);
    throw InputError(where, key.empty() ? what : fmt::format("key '{}': {}", key, what));
  }

  std::string Path(const std::string& parent, const std::string& key) const {
    return parent.empty() ? key : parent + "." + key;
  }

  // Every key of `map` must be one of `known`.
  void CheckKeys(const YAML::Node& map, const std::string& path,
                 const std::vector<std::string>& known) const {
    if (!map.IsMap()) Fail(map, path, "expected a map of keys (" + Join(known) + ")");
    for (const auto& item : map) {
      const std::string key = item.first.Scalar();
      if (std::find(known.begin(), known.end(), key) == known.end()) {
        Fail(item.first, Path(path, key),
             fmt::format("unknown key{}; known keys{}: {}", Suggest(key, known),
                         path.empty() ? "" : " in '" + path + "'", Join(known)));
      }
    }
  }

  YAML::Node Required(const YAML::Node& map, const std::string& parent,
                      const std::string& key) const {
    const YAML::Node node = map[key];
    if (!node.IsDefined() || node.IsNull()) Fail(map, Path(parent, key), "required key is missing");
    return node;
  }

  std::string String(const YAML::Node& node, const std::string& key) const {
    if (!node.IsScalar()) Fail(node, key, "expected a text value");
    return node.Scalar();
  }

  double Double(const YAML::Node& node, const std::string& key) const {
    if (!node.IsScalar()) Fail(node, key, "expected a number");
    const auto value = ParseDouble(Trim(node.Scalar()));
    if (!value) Fail(node, key, fmt::format("expected a number, got '{}'", node.Scalar()));
    return *value;
  }

  double Positive(const YAML::Node& node, const std::string& key) const {
    const double value = Double(node, key);
    if (!(value > 0.0))
      Fail(node, key, fmt::format("expected a number > 0, got {}", node.Scalar()));
    return value;
  }

  int Int(const YAML::Node& node, const std::string& key, int min_value) const {
    if (!node.IsScalar()) Fail(node, key, "expected an integer");
    int value = 0;
    const std::string text = Trim(node.Scalar());
    const auto result = std::from_chars(text.data(), text.data() + text.size(), value);
    if (result.ec != std::errc() || result.ptr != text.data() + text.size()) {
      Fail(node, key, fmt::format("expected an integer, got '{}'", node.Scalar()));
    }
    if (value < min_value) {
      Fail(node, key, fmt::format("expected an integer >= {}, got {}", min_value, value));
    }
    return value;
  }

  const fs::path& file() const { return file_; }

 private:
  fs::path file_;
};

CameraSpec ReadCamera(const YamlReader& yaml, const YAML::Node& node) {
  yaml.CheckKeys(node, "camera",
                 {"pixel_pitch_um", "focal_length_mm", "lens_model", "gamma", "sample_bits"});
  CameraSpec camera;
  camera.pixel_pitch_um =
      yaml.Positive(yaml.Required(node, "camera", "pixel_pitch_um"), "camera.pixel_pitch_um");
  camera.focal_length_mm =
      yaml.Positive(yaml.Required(node, "camera", "focal_length_mm"), "camera.focal_length_mm");
  if (node["lens_model"].IsDefined() && !node["lens_model"].IsNull()) {
    const std::string model = yaml.String(node["lens_model"], "camera.lens_model");
    // Checked here, not first by the calibration (which named neither the
    // file's path nor the line).
    if (!IsValidLensModel(model)) {
      yaml.Fail(node["lens_model"], "camera.lens_model",
                fmt::format("expected a mrcal lens model, configured where it needs it, such as "
                            "LENSMODEL_OPENCV8 or LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_"
                            "Ny=12_fov_x_deg=100; got '{}'",
                            model));
    }
    camera.lens_model = model;
  }
  if (const YAML::Node gamma = node["gamma"]; gamma.IsDefined() && !gamma.IsNull()) {
    camera.gamma = yaml.Double(gamma, "camera.gamma");
    if (!(camera.gamma >= 0.2 && camera.gamma <= 5.0)) {
      yaml.Fail(
          gamma, "camera.gamma",
          fmt::format("expected the camera's gamma in [0.2, 5] (1: linear), got {}", camera.gamma));
    }
  }
  if (const YAML::Node bits = node["sample_bits"]; bits.IsDefined() && !bits.IsNull()) {
    camera.sample_bits = yaml.Int(bits, "camera.sample_bits", 8);
    if (*camera.sample_bits > 16) {
      yaml.Fail(bits, "camera.sample_bits",
                fmt::format("expected the bits of the camera's samples, 8 to 16, got {}",
                            *camera.sample_bits));
    }
  }
  return camera;
}

CalibrationSource ReadCalibration(const YamlReader& yaml, const YAML::Node& node,
                                  const fs::path& dir) {
  yaml.CheckKeys(node, "calibration", {"from"});
  const YAML::Node from = yaml.Required(node, "calibration", "from");
  const std::string text = yaml.String(from, "calibration.from");
  CalibrationSource source;
  source.path = fs::weakly_canonical(dir / text);
  std::error_code ec;
  if (fs::is_directory(source.path, ec)) {
    if (!fs::is_regular_file(source.path / "project.yaml", ec)) {
      yaml.Fail(from, "calibration.from",
                fmt::format("'{}' is a directory but not an omm project (no project.yaml in it)",
                            source.path.string()));
    }
    source.kind = CalibrationSource::Kind::kProject;
  } else if (fs::is_regular_file(source.path, ec)) {
    if (source.path.extension() != ".cameramodel") {
      yaml.Fail(
          from, "calibration.from",
          fmt::format("'{}' is neither an omm project directory nor a mrcal .cameramodel file",
                      source.path.string()));
    }
    source.kind = CalibrationSource::Kind::kCameraModel;
  } else {
    yaml.Fail(from, "calibration.from",
              fmt::format("'{}' does not exist (expected an earlier omm project directory or a "
                          "mrcal .cameramodel file; relative paths are relative to the project)",
                          source.path.string()));
  }
  return source;
}

BoardSpec ReadBoard(const YamlReader& yaml, const YAML::Node& node) {
  yaml.CheckKeys(node, "board",
                 {"type", "rows", "cols", "pitch_mm", "dot_diameter_mm", "frame_mm", "frame_bar_mm",
                  "triangle_mm"});
  BoardSpec board;
  const YAML::Node type_node = yaml.Required(node, "board", "type");
  const std::string type = yaml.String(type_node, "board.type");
  const std::vector<std::string> types = {"caltab", "circles", "chessboard"};
  const std::optional<BoardType> board_type = BoardTypeFromName(type);
  if (!board_type) {
    yaml.Fail(type_node, "board.type",
              fmt::format("unknown board type '{}'{}; expected one of {}", type,
                          Suggest(type, types), Join(types)));
  }
  board.type = *board_type;
  board.rows = yaml.Int(yaml.Required(node, "board", "rows"), "board.rows", 2);
  board.cols = yaml.Int(yaml.Required(node, "board", "cols"), "board.cols", 2);
  board.pitch_mm = yaml.Positive(yaml.Required(node, "board", "pitch_mm"), "board.pitch_mm");

  const bool dots = board.type != BoardType::kChessboard;
  const bool caltab = board.type == BoardType::kCaltab;
  for (const char* key : {"dot_diameter_mm", "frame_mm", "frame_bar_mm", "triangle_mm"}) {
    const bool allowed = std::string(key) == "dot_diameter_mm" ? dots : caltab;
    if (node[key].IsDefined() && !allowed) {
      yaml.Fail(node[key], std::string("board.") + key,
                fmt::format("not used by a '{}' board", type));
    }
  }
  if (dots) {
    const YAML::Node diameter = yaml.Required(node, "board", "dot_diameter_mm");
    board.dot_diameter_mm = yaml.Positive(diameter, "board.dot_diameter_mm");
    if (board.dot_diameter_mm >= board.pitch_mm) {
      yaml.Fail(diameter, "board.dot_diameter_mm",
                fmt::format("the dots ({} mm) must be smaller than their pitch ({} mm)",
                            board.dot_diameter_mm, board.pitch_mm));
    }
  }
  if (caltab) {
    if (node["frame_mm"].IsDefined())
      board.frame_mm = yaml.Positive(node["frame_mm"], "board.frame_mm");
    if (node["frame_bar_mm"].IsDefined()) {
      board.frame_bar_mm = yaml.Positive(node["frame_bar_mm"], "board.frame_bar_mm");
    }
    if (node["triangle_mm"].IsDefined()) {
      board.triangle_mm = yaml.Positive(node["triangle_mm"], "board.triangle_mm");
    }
    const double inner_mm = board.frame_mm - 2.0 * board.frame_bar_mm;
    const double extent_mm =
        std::max(board.rows, board.cols) * board.pitch_mm - board.pitch_mm + board.dot_diameter_mm;
    if (extent_mm >= inner_mm) {
      yaml.Fail(node, "board",
                fmt::format("the {} x {} dots span {} mm, more than the frame's inside ({} mm = "
                            "frame_mm - 2 frame_bar_mm)",
                            board.rows, board.cols, extent_mm, inner_mm));
    }
  }
  return board;
}

FeatureSpec ReadFeature(const YamlReader& yaml, const YAML::Node& node, const std::string& path) {
  yaml.CheckKeys(node, path, {"name", "type", "image", "near_px", "diameter_mm"});
  FeatureSpec feature;
  feature.name = yaml.String(yaml.Required(node, path, "name"), path + ".name");
  CheckName(feature.name, yaml.file().string(), "feature " + path);
  const YAML::Node type_node = yaml.Required(node, path, "type");
  const std::string type = yaml.String(type_node, path + ".type");
  if (type != "circle") {
    yaml.Fail(type_node, path + ".type",
              fmt::format("unknown feature type '{}'; expected circle", type));
  }
  feature.type = FeatureType::kCircle;
  feature.image = yaml.String(yaml.Required(node, path, "image"), path + ".image");
  const YAML::Node near = yaml.Required(node, path, "near_px");
  if (!near.IsSequence() || near.size() != 2) {
    yaml.Fail(near, path + ".near_px", "expected two numbers [x, y] (pixels of the raw tile)");
  }
  feature.near_px = {yaml.Double(near[0], path + ".near_px"),
                     yaml.Double(near[1], path + ".near_px")};
  feature.diameter_mm =
      yaml.Positive(yaml.Required(node, path, "diameter_mm"), path + ".diameter_mm");
  return feature;
}

MeasurementSpec ReadMeasurement(const YamlReader& yaml, const YAML::Node& node,
                                const std::string& path) {
  yaml.CheckKeys(node, path, {"name", "type", "between", "of"});
  MeasurementSpec measurement;
  measurement.name = yaml.String(yaml.Required(node, path, "name"), path + ".name");
  CheckName(measurement.name, yaml.file().string(), "measurement " + path);
  const YAML::Node type_node = yaml.Required(node, path, "type");
  const std::string type = yaml.String(type_node, path + ".type");
  if (type == "distance") {
    measurement.type = MeasurementType::kDistance;
    if (node["of"].IsDefined()) {
      yaml.Fail(node["of"], path + ".of", "a distance names its two circles with 'between'");
    }
    const YAML::Node between = yaml.Required(node, path, "between");
    if (!between.IsSequence() || between.size() != 2) {
      yaml.Fail(between, path + ".between",
                fmt::format("a distance is between exactly two features, e.g. [hole_A, hole_B]; "
                            "got {}",
                            between.IsSequence() ? std::to_string(between.size()) + " items"
                                                 : "'" + between.Scalar() + "'"));
    }
    for (const auto& item : between) {
      measurement.features.push_back(yaml.String(item, path + ".between"));
    }
    if (measurement.features[0] == measurement.features[1]) {
      yaml.Fail(between, path + ".between", "the two features must differ");
    }
  } else if (type == "diameter") {
    measurement.type = MeasurementType::kDiameter;
    if (node["between"].IsDefined()) {
      yaml.Fail(node["between"], path + ".between", "a diameter names its circle with 'of'");
    }
    const YAML::Node of = yaml.Required(node, path, "of");
    if (!of.IsScalar()) yaml.Fail(of, path + ".of", "a diameter is of exactly one feature");
    measurement.features.push_back(of.Scalar());
  } else {
    const std::vector<std::string> types = {"distance", "diameter"};
    yaml.Fail(type_node, path + ".type",
              fmt::format("unknown measurement type '{}'{}; expected one of {}", type,
                          Suggest(type, types), Join(types)));
  }
  return measurement;
}

// project.yaml into `project` (everything but the files it refers to).
void ReadProjectYaml(const fs::path& dir, Project& project, bool& has_table_keys) {
  const fs::path file = dir / "project.yaml";
  const YamlReader yaml(file);
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) {
    throw InputError(file.string(), "project.yaml not found (is this an omm project directory?)");
  }
  YAML::Node root;
  try {
    root = YAML::LoadFile(file.string());
  } catch (const YAML::ParserException& e) {
    throw InputError(fmt::format("{}:{}", file.string(), e.mark.line + 1),
                     "not valid YAML: " + e.msg);
  } catch (const YAML::Exception& e) {
    throw InputError(file.string(), std::string("cannot read: ") + e.what());
  }
  if (!root.IsMap())
    throw InputError(file.string(), "expected a YAML map (format: ..., name: ...)");
  yaml.CheckKeys(root, "", ProjectYamlKeys());
  for (const auto& item : root) {
    YAML::Emitter emitted;
    emitted << item.second;
    project.yaml_sections[item.first.Scalar()] = emitted.c_str();
  }

  const YAML::Node format = yaml.Required(root, "", "format");
  if (yaml.String(format, "format") != kProjectFormat) {
    yaml.Fail(format, "format",
              fmt::format("this omm reads '{}', got '{}'", kProjectFormat, format.Scalar()));
  }
  project.name =
      root["name"].IsDefined() ? yaml.String(root["name"], "name") : dir.filename().string();
  project.camera = ReadCamera(yaml, yaml.Required(root, "", "camera"));
  if (root["calibration"].IsDefined()) {
    project.calibration_from = ReadCalibration(yaml, root["calibration"], dir);
  }
  if (root["board"].IsDefined()) project.board = ReadBoard(yaml, root["board"]);
  if (!project.calibration_from && !project.board) {
    yaml.Fail(root, "board",
              "required key is missing: calib/ is used (no 'calibration.from'), so the plate it "
              "shows must be described");
  }

  has_table_keys = root["table"].IsDefined();
  if (has_table_keys) {
    yaml.CheckKeys(root["table"], "table", {"sigma_mm"});
    project.table_sigma_mm =
        yaml.Positive(yaml.Required(root["table"], "table", "sigma_mm"), "table.sigma_mm");
  }
  if (root["mosaic"].IsDefined()) {
    yaml.CheckKeys(root["mosaic"], "mosaic", {"gsd_mm", "plate_height_mm"});
    project.mosaic_gsd_mm =
        yaml.Positive(yaml.Required(root["mosaic"], "mosaic", "gsd_mm"), "mosaic.gsd_mm");
    if (const YAML::Node height = root["mosaic"]["plate_height_mm"];
        height.IsDefined() && !height.IsNull()) {
      project.plate_height_mm = yaml.Double(height, "mosaic.plate_height_mm");
      if (!(*project.plate_height_mm >= 0.0)) {
        yaml.Fail(height, "mosaic.plate_height_mm",
                  fmt::format("expected a number >= 0, got {}", height.Scalar()));
      }
    }
  }

  std::set<std::string> feature_names;
  if (const YAML::Node features = root["features"]; features.IsDefined() && !features.IsNull()) {
    if (!features.IsSequence()) yaml.Fail(features, "features", "expected a list of features");
    for (size_t i = 0; i < features.size(); ++i) {
      FeatureSpec feature = ReadFeature(yaml, features[i], fmt::format("features[{}]", i));
      if (!feature_names.insert(feature.name).second) {
        yaml.Fail(features[i], fmt::format("features[{}].name", i),
                  fmt::format("duplicate feature name '{}'", feature.name));
      }
      project.features.push_back(std::move(feature));
    }
  }
  std::set<std::string> measurement_names;
  if (const YAML::Node list = root["measurements"]; list.IsDefined() && !list.IsNull()) {
    if (!list.IsSequence()) yaml.Fail(list, "measurements", "expected a list of measurements");
    const std::vector<std::string> names(feature_names.begin(), feature_names.end());
    for (size_t i = 0; i < list.size(); ++i) {
      const std::string path = fmt::format("measurements[{}]", i);
      MeasurementSpec measurement = ReadMeasurement(yaml, list[i], path);
      if (!measurement_names.insert(measurement.name).second) {
        yaml.Fail(list[i], path + ".name",
                  fmt::format("duplicate measurement name '{}'", measurement.name));
      }
      for (const std::string& feature : measurement.features) {
        if (feature_names.count(feature) == 0) {
          yaml.Fail(list[i], path,
                    fmt::format("measurement '{}' names feature '{}', which is not in "
                                "'features'{}",
                                measurement.name, feature, Suggest(feature, names)));
        }
      }
      project.measurements.push_back(std::move(measurement));
    }
  }
}

// ------------------------------------------------------------------ csv ---

struct CsvRow {
  int line = 0;  // 1-based line number in the file
  std::vector<std::string> fields;
};

// A small comma-separated file with a fixed header, `header` or, if
// `optional` is given, `header` followed by `optional` (every row then has
// those columns too); no quoting (names may not contain commas). Blank lines
// are skipped; fields are trimmed.
std::vector<CsvRow> ReadCsv(const fs::path& file, std::vector<std::string> header,
                            const std::vector<std::string>& optional = {}) {
  std::vector<std::string> with_optional = header;
  with_optional.insert(with_optional.end(), optional.begin(), optional.end());
  const std::string expected = optional.empty()
                                   ? fmt::format("'{}'", Join(header))
                                   : fmt::format("'{}' or '{}'", Join(header), Join(with_optional));
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string(), "cannot open file");
  std::vector<CsvRow> rows;
  std::string text;
  int line = 0;
  bool header_seen = false;
  while (std::getline(in, text)) {
    ++line;
    if (line == 1 && text.rfind("\xEF\xBB\xBF", 0) == 0) text.erase(0, 3);  // UTF-8 BOM
    if (Trim(text).empty()) continue;
    CsvRow row{line, {}};
    std::stringstream fields(text);
    std::string field;
    while (std::getline(fields, field, ',')) row.fields.push_back(Trim(field));
    if (!text.empty() && Trim(text).back() == ',') row.fields.push_back("");
    if (!header_seen) {
      if (!optional.empty() && row.fields == with_optional) header = with_optional;
      if (row.fields != header) {
        throw InputError(fmt::format("{}:{}", file.string(), line),
                         fmt::format("expected the header {}, got '{}'", expected, Trim(text)));
      }
      header_seen = true;
      continue;
    }
    if (row.fields.size() != header.size()) {
      throw InputError(fmt::format("{}:{}", file.string(), line),
                       fmt::format("expected {} columns ({}), got {}", header.size(), Join(header),
                                   row.fields.size()));
    }
    rows.push_back(std::move(row));
  }
  if (!header_seen) {
    throw InputError(file.string(), fmt::format("empty file; expected the header {}", expected));
  }
  return rows;
}

double CsvNumber(const fs::path& file, const CsvRow& row, size_t column,
                 const std::string& column_name) {
  const auto value = ParseDouble(row.fields[column]);
  if (!value) {
    throw InputError(
        fmt::format("{}:{}", file.string(), row.line),
        fmt::format("column '{}': expected a number, got '{}'", column_name, row.fields[column]));
  }
  return *value;
}

// --------------------------------------------------------------- images ---

bool IsImageFile(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext == ".png" || ext == ".tif" || ext == ".tiff" || ext == ".jpg" || ext == ".jpeg" ||
         ext == ".pgm" || ext == ".ppm";
}

// Image file names in `dir`, sorted by name. Hidden and non-image files are
// ignored (a README beside the images is harmless).
std::vector<std::string> ListImages(const fs::path& dir) {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name[0] == '.' || !entry.is_regular_file(ec)) continue;
    if (IsImageFile(entry.path())) names.push_back(name);
  }
  if (ec) throw InputError(dir.string(), "cannot list directory: " + ec.message());
  std::sort(names.begin(), names.end());
  return names;
}

// tiles/ and table.csv: each tile's image and table position. Both or
// neither (a calibration-only project); the keys they need are checked too.
void ReadTiles(const fs::path& dir, bool has_table_keys, Project& project) {
  std::error_code ec;
  const fs::path yaml_file = dir / "project.yaml";
  const fs::path tiles_dir = dir / "tiles";
  const fs::path table_file = dir / "table.csv";
  const bool has_tiles = fs::is_directory(tiles_dir, ec);
  const bool has_table = fs::is_regular_file(table_file, ec);
  if (has_tiles != has_table) {
    throw InputError(has_tiles ? table_file.string() : tiles_dir.string(),
                     has_tiles
                         ? "table.csv not found (tiles/ needs the table position of each tile)"
                         : "tiles/ not found (table.csv lists tiles)");
  }
  if (!has_tiles && !project.features.empty()) {
    throw InputError(tiles_dir.string(),
                     "tiles/ not found (project.yaml lists features to find in the tiles)");
  }
  if (has_tiles) {
    if (!has_table_keys) {
      throw InputError(yaml_file.string(), "key 'table.sigma_mm': required key is missing");
    }
    if (project.mosaic_gsd_mm <= 0.0) {
      throw InputError(yaml_file.string(), "key 'mosaic.gsd_mm': required key is missing");
    }
    const std::vector<std::string> images = ListImages(tiles_dir);
    if (images.empty()) throw InputError(tiles_dir.string(), "no images (PNG, TIFF or JPEG)");
    std::map<std::string, Eigen::Vector2d> positions;
    for (const CsvRow& row : ReadCsv(table_file, {"image", "x_mm", "y_mm"})) {
      const std::string where = fmt::format("{}:{}", table_file.string(), row.line);
      const std::string& image = row.fields[0];
      CheckName(image, where, "image");
      // x before y: a row with both wrong names its first bad column.
      const double x_mm = CsvNumber(table_file, row, 1, "x_mm");
      const Eigen::Vector2d pos(x_mm, CsvNumber(table_file, row, 2, "y_mm"));
      if (!positions.emplace(image, pos).second) {
        throw InputError(where, fmt::format("tile '{}' is listed twice", image));
      }
      if (!std::binary_search(images.begin(), images.end(), image)) {
        throw InputError(where, fmt::format("tile '{}' has no image in tiles/{}", image,
                                            Suggest(image, images)));
      }
    }
    for (const std::string& image : images) {
      const auto it = positions.find(image);
      if (it == positions.end()) {
        throw InputError((tiles_dir / image).string(),
                         "this tile has no row in table.csv (its table position is needed)");
      }
      project.tiles.push_back({image, it->second});
    }
    if (project.tiles.size() < 2) {
      throw InputError(table_file.string(), "a mosaic needs at least 2 tiles");
    }
    if (std::all_of(project.tiles.begin(), project.tiles.end(), [&](const TilePosition& tile) {
          return tile.table_pos_mm == project.tiles.front().table_pos_mm;
        })) {
      throw InputError(table_file.string(),
                       "every tile is at one table position: a mosaic needs the table to move "
                       "between tiles (its motion is the mosaic's scale)");
    }
    for (size_t i = 0; i < project.features.size(); ++i) {
      const FeatureSpec& feature = project.features[i];
      if (positions.count(feature.image) == 0) {
        throw InputError(
            yaml_file.string(),
            fmt::format("key 'features[{}].image': feature '{}' is seen in '{}', "
                        "which is not a tile in tiles/ and table.csv{}",
                        i, feature.name, feature.image, Suggest(feature.image, images)));
      }
    }
  }
}

// cmm.csv, if there is one: a CMM value per measurement of project.yaml.
void ReadCmm(const fs::path& dir, Project& project) {
  std::error_code ec;
  const fs::path cmm_file = dir / "cmm.csv";
  if (fs::is_regular_file(cmm_file, ec)) {
    std::vector<std::string> names;
    for (const MeasurementSpec& m : project.measurements) names.push_back(m.name);
    std::set<std::string> seen;
    for (const CsvRow& row : ReadCsv(cmm_file, {"name", "value_mm"}, {"sigma_mm"})) {
      const std::string where = fmt::format("{}:{}", cmm_file.string(), row.line);
      const std::string& name = row.fields[0];
      if (std::find(names.begin(), names.end(), name) == names.end()) {
        throw InputError(where, fmt::format("'{}' is not a measurement in project.yaml{}", name,
                                            Suggest(name, names)));
      }
      if (!seen.insert(name).second) {
        throw InputError(where, fmt::format("'{}' is listed twice", name));
      }
      CmmValue value{name, CsvNumber(cmm_file, row, 1, "value_mm"), std::nullopt};
      // An empty sigma_mm: this value's uncertainty is not stated.
      if (row.fields.size() > 2 && !row.fields[2].empty()) {
        value.sigma_mm = CsvNumber(cmm_file, row, 2, "sigma_mm");
        if (!(*value.sigma_mm > 0.0)) {
          throw InputError(where, fmt::format("column 'sigma_mm': expected a number > 0 (or "
                                              "nothing: not stated), got '{}'",
                                              row.fields[2]));
        }
      }
      project.cmm.push_back(std::move(value));
    }
  }
}

// calib/'s images, used only when no earlier calibration is reused.
void ListCalibImages(const fs::path& dir, Project& project) {
  std::error_code ec;
  if (!project.calibration_from) {
    const fs::path calib_dir = dir / "calib";
    if (!fs::is_directory(calib_dir, ec)) {
      throw InputError(calib_dir.string(),
                       "calib/ not found (needed unless project.yaml sets 'calibration.from')");
    }
    for (const std::string& name : ListImages(calib_dir)) {
      project.calib_images.push_back(calib_dir / name);
    }
    if (project.calib_images.empty()) {
      throw InputError(calib_dir.string(), "no images (PNG, TIFF or JPEG)");
    }
  }
}

// A 16-bit image's largest sample.
std::uint16_t LargestSample(const StoredImage& image) {
  const auto* samples = reinterpret_cast<const std::uint16_t*>(image.samples.data());
  const std::size_t count = image.samples.size() / 2;
  return count > 0 ? *std::max_element(samples, samples + count) : 0;
}

// Project::sample_bits of these images (paths: theirs, for errors): the
// camera's stated bits, checked against every 16-bit image, or the fewest
// that hold every sample.
int SampleBits(const CameraSpec& camera, const std::vector<LoadedImage>& loaded,
               const std::vector<fs::path>& paths) {
  if (camera.sample_bits) {
    const int full_scale = (1 << *camera.sample_bits) - 1;
    for (size_t i = 0; i < loaded.size(); ++i) {
      if (loaded[i].image->bit_depth != 16) continue;
      if (const int largest = LargestSample(*loaded[i].image); largest > full_scale) {
        throw InputError(paths[i].string(),
                         fmt::format("a sample of {}, beyond the full scale {} of "
                                     "project.yaml's camera.sample_bits {}",
                                     largest, full_scale, *camera.sample_bits));
      }
    }
    return *camera.sample_bits;
  }
  std::uint16_t largest = 0;
  for (const LoadedImage& file : loaded) {
    if (file.image->bit_depth != 16) return 16;
    largest = std::max(largest, LargestSample(*file.image));
  }
  for (const int bits : {10, 12, 14})
    if (largest < (1 << bits)) return bits;
  return 16;
}

// Every image read, hashed and decoded once, here: a corrupt file is found
// now, not halfway through, and the stages take the decoded images from
// memory. All must have one size.
void LoadImages(const fs::path& dir, int num_threads, Project& project) {
  std::vector<fs::path> all_images = project.calib_images;
  for (const TilePosition& tile : project.tiles) all_images.push_back(project.TilePath(tile.image));
  std::vector<LoadedImage> loaded(all_images.size());
  // Throws for the first bad file in file-name order, whatever the threads' order.
  ParallelFor(static_cast<int>(all_images.size()), std::max(1, num_threads), [&](int i) {
    const fs::path& path = all_images[i];
    std::error_code exists_ec;
    if (!fs::is_regular_file(path, exists_ec))
      throw InputError(path.string(), "image file not found");
    const std::string bytes = ReadTextFile(path, "cannot read image file");
    loaded[i].sha256 = Sha256Hex(bytes);
    loaded[i].image = std::make_shared<const StoredImage>(DecodeImage(bytes, path));
  });
  for (size_t i = 0; i < loaded.size(); ++i) {
    const StoredImage& image = *loaded[i].image;
    if (i == 0) {
      project.image_width_px = image.width;
      project.image_height_px = image.height;
    } else if (image.width != project.image_width_px || image.height != project.image_height_px) {
      throw InputError(
          all_images[i].string(),
          fmt::format("image is {} x {} px but {} is {} x {} px; all images of a "
                      "project must have one size",
                      image.width, image.height, fs::relative(all_images[0], dir).string(),
                      project.image_width_px, project.image_height_px));
    }
  }
  project.sample_bits = SampleBits(project.camera, loaded, all_images);
  auto images = std::make_shared<LoadedImages>();
  const auto calib_end = loaded.begin() + static_cast<std::ptrdiff_t>(project.calib_images.size());
  images->calib.assign(std::make_move_iterator(loaded.begin()), std::make_move_iterator(calib_end));
  images->tiles.assign(std::make_move_iterator(calib_end), std::make_move_iterator(loaded.end()));
  project.images = std::move(images);
}

// Each feature's near_px inside its tile.
void CheckFeaturesInTiles(const fs::path& yaml_file, const Project& project) {
  for (size_t i = 0; i < project.features.size(); ++i) {
    const FeatureSpec& feature = project.features[i];
    const Eigen::Vector2d& q = feature.near_px;
    if (q.x() < -0.5 || q.y() < -0.5 || q.x() > project.image_width_px - 0.5 ||
        q.y() > project.image_height_px - 0.5) {
      throw InputError(yaml_file.string(),
                       fmt::format("key 'features[{}].near_px': [{}, {}] is outside the {} x {} "
                                   "px tile '{}'",
                                   i, q.x(), q.y(), project.image_width_px, project.image_height_px,
                                   feature.image));
    }
  }
}

}  // namespace

const std::vector<std::string>& ProjectYamlKeys() {
  static const std::vector<std::string> keys = {"format",      "name",     "camera",
                                                "calibration", "board",    "table",
                                                "mosaic",      "features", "measurements"};
  return keys;
}

Project LoadProject(const fs::path& dir_in, int num_threads) {
  std::error_code ec;
  if (!fs::is_directory(dir_in, ec)) {
    throw InputError(dir_in.string(), "project directory not found");
  }
  Project project;
  project.dir = fs::canonical(dir_in);
  const fs::path& dir = project.dir;

  bool has_table_keys = false;
  ReadProjectYaml(dir, project, has_table_keys);
  ReadTiles(dir, has_table_keys, project);
  ReadCmm(dir, project);
  if (!project.calibration_from) ListCalibImages(dir, project);
  LoadImages(dir, num_threads, project);
  CheckFeaturesInTiles(dir / "project.yaml", project);
  return project;
}

}  // namespace omm
