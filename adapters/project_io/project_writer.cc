#include "adapters/project_io/project_writer.h"

#include <algorithm>
#include <charconv>
#include <system_error>

#include <yaml-cpp/yaml.h>

#include "adapters/project_io/text_file.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

// Shortest text that reads back to the same double (so a project written and
// read again is bit-identical), e.g. "0.1" rather than "0.10000000000000001".
std::string Number(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

std::string ProjectYaml(const Project& project) {
  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "format" << YAML::Value << "omm-project/1";
  out << YAML::Key << "name" << YAML::Value << project.name;

  out << YAML::Key << "camera" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "pixel_pitch_um" << YAML::Value << Number(project.camera.pixel_pitch_um);
  out << YAML::Key << "focal_length_mm" << YAML::Value << Number(project.camera.focal_length_mm);
  if (project.camera.lens_model) {
    out << YAML::Key << "lens_model" << YAML::Value << *project.camera.lens_model;
  }
  if (project.camera.gamma != 1.0) {
    out << YAML::Key << "gamma" << YAML::Value << Number(project.camera.gamma);
  }
  if (project.camera.sample_bits) {
    out << YAML::Key << "sample_bits" << YAML::Value << *project.camera.sample_bits;
  }
  out << YAML::EndMap;

  if (project.calibration_from) {
    // Relative to the project when possible, so a moved archive keeps working.
    std::filesystem::path from = project.calibration_from->path;
    if (from.is_absolute() && !project.dir.empty()) {
      std::error_code ec;
      const auto relative = std::filesystem::relative(from, project.dir, ec);
      if (!ec && !relative.empty()) from = relative;
    }
    out << YAML::Key << "calibration" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "from" << YAML::Value << from.generic_string();
    out << YAML::EndMap;
  }

  if (project.board) {
    const BoardSpec& board = *project.board;
    out << YAML::Key << "board" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "type" << YAML::Value << BoardTypeName(board.type);
    out << YAML::Key << "rows" << YAML::Value << board.rows;
    out << YAML::Key << "cols" << YAML::Value << board.cols;
    out << YAML::Key << "pitch_mm" << YAML::Value << Number(board.pitch_mm);
    if (board.type != BoardType::kChessboard) {
      out << YAML::Key << "dot_diameter_mm" << YAML::Value << Number(board.dot_diameter_mm);
    }
    if (board.type == BoardType::kCaltab) {
      out << YAML::Key << "frame_mm" << YAML::Value << Number(board.frame_mm);
      out << YAML::Key << "frame_bar_mm" << YAML::Value << Number(board.frame_bar_mm);
      out << YAML::Key << "triangle_mm" << YAML::Value << Number(board.triangle_mm);
    }
    out << YAML::EndMap;
  }

  if (!project.tiles.empty()) {
    out << YAML::Key << "table" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "sigma_mm" << YAML::Value << Number(project.table_sigma_mm);
    out << YAML::EndMap;
    out << YAML::Key << "mosaic" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "gsd_mm" << YAML::Value << Number(project.mosaic_gsd_mm);
    if (project.plate_height_mm) {
      out << YAML::Key << "plate_height_mm" << YAML::Value << Number(*project.plate_height_mm);
    }
    out << YAML::EndMap;
  }

  out << YAML::Key << "features" << YAML::Value << YAML::BeginSeq;
  for (const FeatureSpec& feature : project.features) {
    out << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << feature.name;
    out << YAML::Key << "type" << YAML::Value << FeatureTypeName(feature.type);
    out << YAML::Key << "image" << YAML::Value << feature.image;
    out << YAML::Key << "near_px" << YAML::Value << YAML::Flow << YAML::BeginSeq
        << Number(feature.near_px.x()) << Number(feature.near_px.y()) << YAML::EndSeq;
    out << YAML::Key << "diameter_mm" << YAML::Value << Number(feature.diameter_mm);
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;

  out << YAML::Key << "measurements" << YAML::Value << YAML::BeginSeq;
  for (const MeasurementSpec& measurement : project.measurements) {
    out << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << measurement.name;
    out << YAML::Key << "type" << YAML::Value << MeasurementTypeName(measurement.type);
    if (measurement.type == MeasurementType::kDistance) {
      out << YAML::Key << "between" << YAML::Value << YAML::Flow << measurement.features;
    } else {
      out << YAML::Key << "of" << YAML::Value
          << (measurement.features.empty() ? std::string() : measurement.features.front());
    }
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::EndMap;
  if (!out.good()) throw InputError("project.yaml", "cannot emit: " + out.GetLastError());
  return std::string(out.c_str()) + "\n";
}

}  // namespace

void WriteProjectFiles(const Project& project) {
  std::error_code ec;
  std::filesystem::create_directories(project.dir, ec);
  if (ec) throw InputError(project.dir.string(), "cannot create directory: " + ec.message());

  WriteTextFileAtomically(project.dir / "project.yaml", ProjectYaml(project));

  if (!project.tiles.empty()) {
    std::string table = "image,x_mm,y_mm\n";
    for (const TilePosition& tile : project.tiles) {
      table += tile.image + "," + Number(tile.table_pos_mm.x()) + "," +
               Number(tile.table_pos_mm.y()) + "\n";
    }
    WriteTextFileAtomically(project.dir / "table.csv", table);
  }

  if (!project.cmm.empty()) {
    // The sigma_mm column only where some value states its sigma.
    const bool with_sigma = std::any_of(project.cmm.begin(), project.cmm.end(),
                                        [](const CmmValue& v) { return v.sigma_mm.has_value(); });
    std::string cmm = with_sigma ? "name,value_mm,sigma_mm\n" : "name,value_mm\n";
    for (const CmmValue& value : project.cmm) {
      cmm += value.measurement + "," + Number(value.value_mm);
      if (with_sigma) cmm += ',';
      if (value.sigma_mm) cmm += Number(*value.sigma_mm);
      cmm += '\n';
    }
    WriteTextFileAtomically(project.dir / "cmm.csv", cmm);
  }
}

}  // namespace omm
