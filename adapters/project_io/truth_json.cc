#include "adapters/project_io/truth_json.h"

#include <nlohmann/json.hpp>

#include "adapters/project_io/json_reader.h"
#include "adapters/project_io/text_file.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

using nlohmann::json;

constexpr const char* kFormat = "omm-truth/1";

json Pose(const Eigen::Isometry3d& pose) {
  json rows = json::array();
  for (int r = 0; r < 3; ++r) rows.push_back(JsonArray(pose.linear().row(r).transpose()));
  const Eigen::AngleAxisd angle_axis(pose.linear());
  return {{"R", rows},
          {"t", JsonArray(pose.translation())},
          {"r", JsonArray(angle_axis.angle() * angle_axis.axis())}};
}

json Exposure(const ExposureTruth& exposure) {
  return {{"gain", exposure.gain},
          {"vignetting", exposure.vignetting},
          {"psf_sigma_px", exposure.psf_sigma_px}};
}

Eigen::Isometry3d ReadPose(const JsonReader& in, const json& node, const std::string& path) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  const json& rows = in.Array(node, "R", path);
  if (rows.size() != 3) in.Fail(path + ".R", "expected 3 rows");
  for (int r = 0; r < 3; ++r) {
    const json wrapped = {{"row", rows[r]}};
    pose.linear().row(r) = in.Vector(wrapped, "row", path + ".R[" + std::to_string(r) + "]", 3);
  }
  pose.translation() = in.Vector(node, "t", path, 3);
  return pose;
}

ExposureTruth ReadExposure(const JsonReader& in, const json& node, const std::string& path) {
  ExposureTruth exposure;
  exposure.gain = in.Number(node, "gain", path);
  exposure.vignetting = in.Number(node, "vignetting", path);
  exposure.psf_sigma_px = in.Number(node, "psf_sigma_px", path);
  return exposure;
}

}  // namespace

std::string TruthToJson(const SimulationTruth& truth) {
  json root;
  root["format"] = kFormat;
  root["preset"] = truth.preset;
  root["seed"] = truth.seed;

  const CameraModel& model = truth.camera.model;
  root["camera"] = {{"lens_model", model.lens_model},
                    {"intrinsics", JsonArray(model.intrinsics)},
                    {"imager_size_px", {model.width_px, model.height_px}},
                    {"pixel_pitch_um", truth.camera.pixel_pitch_um},
                    {"focal_length_mm", truth.camera.focal_length_mm},
                    {"psf_sigma_px", truth.camera.psf_sigma_px}};

  const BoardSpec& board = truth.board;
  root["board"] = {{"type", BoardTypeName(board.type)},
                   {"rows", board.rows},
                   {"cols", board.cols},
                   {"pitch_mm", board.pitch_mm},
                   {"dot_diameter_mm", board.dot_diameter_mm},
                   {"frame_mm", board.frame_mm},
                   {"frame_bar_mm", board.frame_bar_mm},
                   {"triangle_mm", board.triangle_mm},
                   {"plate_size_mm", truth.plate_size_mm}};

  json calib = json::array();
  for (const CalibImageTruth& image : truth.calib_images) {
    calib.push_back({{"image", image.image},
                     {"kind", CalibImageKindName(image.kind)},
                     {"cam_from_plate", Pose(image.cam_from_plate)},
                     {"exposure", Exposure(image.exposure)}});
  }
  root["calib_images"] = calib;

  root["part"] = {{"cam_from_part", Pose(truth.cam_from_part)},
                  {"outline_min_mm", JsonArray(truth.part_min_mm)},
                  {"outline_max_mm", JsonArray(truth.part_max_mm)},
                  {"thickness_mm", truth.part_thickness_mm}};

  json tiles = json::array();
  for (const TileTruth& tile : truth.tiles) {
    tiles.push_back({{"image", tile.image},
                     {"grid", {tile.grid_row, tile.grid_col}},
                     {"commanded_mm", JsonArray(tile.commanded_mm)},
                     {"actual_mm", JsonArray(tile.actual_mm)},
                     {"exposure", Exposure(tile.exposure)}});
  }
  root["table"] = {{"sigma_mm", truth.table_sigma_mm}, {"tiles", tiles}};

  json holes = json::array();
  for (const HoleTruth& hole : truth.holes) {
    holes.push_back({{"name", hole.name},
                     {"center_mm", JsonArray(hole.center_part_mm)},
                     {"diameter_mm", hole.diameter_mm},
                     {"nominal_diameter_mm", hole.nominal_diameter_mm}});
  }
  root["holes"] = holes;

  json markers = json::array();
  for (const MarkerTruth& marker : truth.markers) {
    json corners = json::array();
    for (int k = 0; k < 4; ++k) corners.push_back(JsonArray(marker.corners_part_mm.col(k)));
    markers.push_back({{"id", marker.id},
                       {"corners_mm", corners},
                       {"tag_size_mm", marker.tag_size_mm},
                       {"paper_size_mm", marker.paper_size_mm}});
  }
  root["markers"] = markers;

  root["part_from_plate"] = truth.part_from_plate ? Pose(*truth.part_from_plate) : json(nullptr);

  json measurements = json::array();
  for (const MeasurementTruth& m : truth.measurements) {
    measurements.push_back({{"name", m.name}, {"value_mm", m.value_mm}});
  }
  root["measurements"] = measurements;
  return root.dump(1) + "\n";
}

SimulationTruth TruthFromJson(const std::string& text, const std::string& where) {
  json root;
  try {
    root = json::parse(text);
  } catch (const json::parse_error& e) {
    throw InputError(where, std::string("not valid JSON: ") + e.what());
  }
  const JsonReader in(where);
  if (in.String(root, "format", "") != kFormat) {
    in.Fail("format", std::string("expected \"") + kFormat + "\"");
  }
  SimulationTruth truth;
  truth.preset = in.String(root, "preset", "");
  const json& seed = in.At(root, "seed", "");
  if (!seed.is_number_unsigned()) in.Fail("seed", "expected an unsigned integer");
  truth.seed = seed.get<std::uint64_t>();

  const json& camera = in.At(root, "camera", "");
  truth.camera.model.lens_model = in.String(camera, "lens_model", "camera");
  truth.camera.model.intrinsics = in.Vector(camera, "intrinsics", "camera");
  const Eigen::VectorXd size = in.Vector(camera, "imager_size_px", "camera", 2);
  truth.camera.model.width_px = static_cast<int>(size[0]);
  truth.camera.model.height_px = static_cast<int>(size[1]);
  truth.camera.pixel_pitch_um = in.Number(camera, "pixel_pitch_um", "camera");
  truth.camera.focal_length_mm = in.Number(camera, "focal_length_mm", "camera");
  truth.camera.psf_sigma_px = in.Number(camera, "psf_sigma_px", "camera");

  const json& board = in.At(root, "board", "");
  const std::string type = in.String(board, "type", "board");
  const std::optional<BoardType> board_type = BoardTypeFromName(type);
  if (!board_type) in.Fail("board.type", "expected caltab, circles or chessboard");
  truth.board.type = *board_type;
  truth.board.rows = in.Int(board, "rows", "board");
  truth.board.cols = in.Int(board, "cols", "board");
  truth.board.pitch_mm = in.Number(board, "pitch_mm", "board");
  truth.board.dot_diameter_mm = in.Number(board, "dot_diameter_mm", "board");
  truth.board.frame_mm = in.Number(board, "frame_mm", "board");
  truth.board.frame_bar_mm = in.Number(board, "frame_bar_mm", "board");
  truth.board.triangle_mm = in.Number(board, "triangle_mm", "board");
  truth.plate_size_mm = in.Number(board, "plate_size_mm", "board");

  const json& calib = in.Array(root, "calib_images", "");
  for (size_t i = 0; i < calib.size(); ++i) {
    const std::string path = "calib_images[" + std::to_string(i) + "]";
    CalibImageTruth image;
    image.image = in.String(calib[i], "image", path);
    const std::string kind = in.String(calib[i], "kind", path);
    if (kind == "full") {
      image.kind = CalibImageTruth::Kind::kFull;
    } else if (kind == "partial") {
      image.kind = CalibImageTruth::Kind::kPartial;
    } else if (kind == "plate-absent") {
      image.kind = CalibImageTruth::Kind::kPlateAbsent;
    } else {
      in.Fail(path + ".kind", "expected full, partial or plate-absent");
    }
    image.cam_from_plate =
        ReadPose(in, in.At(calib[i], "cam_from_plate", path), path + ".cam_from_plate");
    image.exposure = ReadExposure(in, in.At(calib[i], "exposure", path), path + ".exposure");
    truth.calib_images.push_back(image);
  }

  const json& part = in.At(root, "part", "");
  truth.cam_from_part = ReadPose(in, in.At(part, "cam_from_part", "part"), "part.cam_from_part");
  truth.part_min_mm = in.Vec2(part, "outline_min_mm", "part");
  truth.part_max_mm = in.Vec2(part, "outline_max_mm", "part");
  truth.part_thickness_mm = in.Number(part, "thickness_mm", "part");

  const json& table = in.At(root, "table", "");
  truth.table_sigma_mm = in.Number(table, "sigma_mm", "table");
  const json& tiles = in.Array(table, "tiles", "table");
  for (size_t i = 0; i < tiles.size(); ++i) {
    const std::string path = "table.tiles[" + std::to_string(i) + "]";
    TileTruth tile;
    tile.image = in.String(tiles[i], "image", path);
    const Eigen::VectorXd grid = in.Vector(tiles[i], "grid", path, 2);
    tile.grid_row = static_cast<int>(grid[0]);
    tile.grid_col = static_cast<int>(grid[1]);
    tile.commanded_mm = in.Vec2(tiles[i], "commanded_mm", path);
    tile.actual_mm = in.Vec2(tiles[i], "actual_mm", path);
    tile.exposure = ReadExposure(in, in.At(tiles[i], "exposure", path), path + ".exposure");
    truth.tiles.push_back(tile);
  }

  const json& holes = in.Array(root, "holes", "");
  for (size_t i = 0; i < holes.size(); ++i) {
    const std::string path = "holes[" + std::to_string(i) + "]";
    HoleTruth hole;
    hole.name = in.String(holes[i], "name", path);
    hole.center_part_mm = in.Vec2(holes[i], "center_mm", path);
    hole.diameter_mm = in.Number(holes[i], "diameter_mm", path);
    hole.nominal_diameter_mm = in.Number(holes[i], "nominal_diameter_mm", path);
    truth.holes.push_back(hole);
  }

  const json& markers = in.Array(root, "markers", "");
  for (size_t i = 0; i < markers.size(); ++i) {
    const std::string path = "markers[" + std::to_string(i) + "]";
    MarkerTruth marker;
    marker.id = in.Int(markers[i], "id", path);
    const json& corners = in.Array(markers[i], "corners_mm", path);
    if (corners.size() != 4) in.Fail(path + ".corners_mm", "expected 4 corners");
    for (int k = 0; k < 4; ++k) {
      const json wrapped = {{"corner", corners[k]}};
      marker.corners_part_mm.col(k) =
          in.Vec2(wrapped, "corner", path + ".corners_mm[" + std::to_string(k) + "]");
    }
    marker.tag_size_mm = in.Number(markers[i], "tag_size_mm", path);
    marker.paper_size_mm = in.Number(markers[i], "paper_size_mm", path);
    truth.markers.push_back(marker);
  }

  const json& plate = in.At(root, "part_from_plate", "");
  if (!plate.is_null()) truth.part_from_plate = ReadPose(in, plate, "part_from_plate");

  const json& measurements = in.Array(root, "measurements", "");
  for (size_t i = 0; i < measurements.size(); ++i) {
    const std::string path = "measurements[" + std::to_string(i) + "]";
    truth.measurements.push_back(
        {in.String(measurements[i], "name", path), in.Number(measurements[i], "value_mm", path)});
  }
  return truth;
}

void WriteTruthJson(const SimulationTruth& truth, const std::filesystem::path& path) {
  WriteTextFileAtomically(path, TruthToJson(truth));
}

SimulationTruth ReadTruthJson(const std::filesystem::path& path) {
  return TruthFromJson(ReadTextFile(path, "truth file not found"), path.string());
}

}  // namespace omm
