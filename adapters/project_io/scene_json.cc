#include "adapters/project_io/scene_json.h"

#include <algorithm>

#include <nlohmann/json.hpp>

#include "adapters/project_io/json_reader.h"
#include "adapters/project_io/text_file.h"
#include "pipeline/core/error.h"

namespace omm {

using nlohmann::json;

namespace {

// {"size": N, "values": [N x N, row-major]}, or null if empty.
json SquareMatrixJson(const Eigen::MatrixXd& m) {
  if (m.size() == 0) return nullptr;
  json values = json::array();
  for (Eigen::Index r = 0; r < m.rows(); ++r) {
    for (Eigen::Index c = 0; c < m.cols(); ++c) values.push_back(m(r, c));
  }
  return {{"size", m.rows()}, {"values", values}};
}

// SquareMatrixJson's matrix at root[key] (empty if null), `expected` square.
Eigen::MatrixXd SquareMatrixFromJson(const JsonReader& in, const json& root, const std::string& key,
                                     int expected, const std::string& expected_for) {
  const json& node = in.At(root, key, "");
  if (node.is_null()) return {};
  const int size = static_cast<int>(in.Number(node, "size", key));
  if (size != expected) {
    in.Fail(key + ".size", "expected " + std::to_string(expected) + " for " + expected_for);
  }
  const Eigen::VectorXd values = in.Vector(node, "values", key, size * size);
  return Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
      values.data(), size, size);
}

}  // namespace

std::string SceneToJson(const SavedScene& saved) {
  const PlaneScene& scene = saved.scene;
  json root;
  root["format"] = kSceneFormat;
  root["cam_from_part"] = {{"r", JsonArray(scene.cam_from_part_r)},
                           {"t", JsonArray(scene.cam_from_part_t_mm)}};
  root["table_sigma_mm"] = saved.table_sigma_mm;
  json tiles = json::array();
  for (size_t i = 0; i < scene.table_pos_mm.size(); ++i) {
    const bool held = std::find(saved.tiles_held_by_prior.begin(), saved.tiles_held_by_prior.end(),
                                static_cast<int>(i)) != saved.tiles_held_by_prior.end();
    tiles.push_back(
        {{"image", saved.tile_images.at(i)},
         {"commanded_mm", JsonArray(saved.commanded_table_pos_mm.at(i))},
         {"adjusted_mm", JsonArray(scene.table_pos_mm[i])},
         {"held_by_prior", held},
         {"table_prior_used",
          !std::binary_search(saved.tiles_without_table_prior.begin(),
                              saved.tiles_without_table_prior.end(), static_cast<int>(i))}});
  }
  root["tiles"] = tiles;
  json plates = json::array();
  for (const PlatePose& plate : scene.plates) {
    plates.push_back({{"x_mm", plate.x_mm},
                      {"y_mm", plate.y_mm},
                      {"theta_rad", plate.theta_rad},
                      {"height_mm", plate.height_mm},
                      {"scale", plate.scale}});
  }
  root["plates"] = plates;
  root["lens_model"] = saved.lens_model;
  root["intrinsics"] = JsonArray(scene.intrinsics);
  root["intrinsics_refined"] = saved.intrinsics_refined;
  root["rms_px"] = saved.rms_px;
  root["intrinsics_information"] = SquareMatrixJson(saved.intrinsics_information);
  root["covariance"] = SquareMatrixJson(scene.covariance);
  return root.dump(2) + "\n";
}

SavedScene SceneFromJson(const std::string& text, const std::string& where) {
  const JsonReader in(where);
  json root;
  try {
    root = json::parse(text);
  } catch (const json::parse_error& e) {
    throw InputError(where, std::string("not valid JSON: ") + e.what());
  }
  const json& format = in.At(root, "format", "");
  if (!format.is_string() || format.get<std::string>() != kSceneFormat) {
    in.Fail("format", std::string("expected \"") + kSceneFormat + "\"");
  }
  SavedScene saved;
  PlaneScene& scene = saved.scene;
  const json& pose = in.At(root, "cam_from_part", "");
  scene.cam_from_part_r = in.Vector(pose, "r", "cam_from_part", 3);
  scene.cam_from_part_t_mm = in.Vector(pose, "t", "cam_from_part", 3);
  saved.table_sigma_mm = in.Number(root, "table_sigma_mm", "");
  if (!(saved.table_sigma_mm > 0.0)) in.Fail("table_sigma_mm", "expected > 0");
  const json& tiles = in.Array(root, "tiles", "");
  for (size_t i = 0; i < tiles.size(); ++i) {
    const std::string path = "tiles[" + std::to_string(i) + "]";
    const json& image = in.At(tiles[i], "image", path);
    if (!image.is_string()) in.Fail(path + ".image", "expected a string");
    saved.tile_images.push_back(image.get<std::string>());
    saved.commanded_table_pos_mm.emplace_back(in.Vector(tiles[i], "commanded_mm", path, 2));
    scene.table_pos_mm.emplace_back(in.Vector(tiles[i], "adjusted_mm", path, 2));
    const json& held = in.At(tiles[i], "held_by_prior", path);
    if (!held.is_boolean()) in.Fail(path + ".held_by_prior", "expected true or false");
    if (held.get<bool>()) saved.tiles_held_by_prior.push_back(static_cast<int>(i));
    // Optional: files written before it existed used every prior.
    if (tiles[i].contains("table_prior_used")) {
      const json& used = tiles[i].at("table_prior_used");
      if (!used.is_boolean()) in.Fail(path + ".table_prior_used", "expected true or false");
      if (!used.get<bool>()) saved.tiles_without_table_prior.push_back(static_cast<int>(i));
    }
  }
  const json& plates = in.Array(root, "plates", "");
  for (size_t k = 0; k < plates.size(); ++k) {
    const std::string path = "plates[" + std::to_string(k) + "]";
    PlatePose plate;
    plate.x_mm = in.Number(plates[k], "x_mm", path);
    plate.y_mm = in.Number(plates[k], "y_mm", path);
    plate.theta_rad = in.Number(plates[k], "theta_rad", path);
    plate.height_mm = in.Number(plates[k], "height_mm", path);
    plate.scale = in.Number(plates[k], "scale", path);
    scene.plates.push_back(plate);
  }
  scene.intrinsics = in.Vector(root, "intrinsics", "");
  // Optional: files written before they existed held the intrinsics.
  if (root.contains("lens_model")) {
    const json& lens_model = root.at("lens_model");
    if (!lens_model.is_string()) in.Fail("lens_model", "expected a string");
    saved.lens_model = lens_model.get<std::string>();
  }
  if (root.contains("intrinsics_refined")) {
    const json& refined = root.at("intrinsics_refined");
    if (!refined.is_boolean()) in.Fail("intrinsics_refined", "expected true or false");
    saved.intrinsics_refined = refined.get<bool>();
  }
  saved.rms_px = in.Number(root, "rms_px", "");
  const int num_intrinsics = static_cast<int>(scene.intrinsics.size());
  if (saved.intrinsics_refined) {
    if (!root.contains("intrinsics_information")) {
      in.Fail("intrinsics_information", "missing (the file predates it): run `omm mosaic` again");
    }
    saved.intrinsics_information =
        SquareMatrixFromJson(in, root, "intrinsics_information", num_intrinsics,
                             std::to_string(num_intrinsics) + " intrinsics");
    if (saved.intrinsics_information.size() == 0)
      in.Fail("intrinsics_information", "null, but the intrinsics were refined");
  }
  scene.covariance = SquareMatrixFromJson(
      in, root, "covariance",
      PlaneSceneCovarianceSize(static_cast<int>(tiles.size()), static_cast<int>(plates.size()),
                               num_intrinsics),
      std::to_string(tiles.size()) + " tiles");
  return saved;
}

void WriteSceneJson(const SavedScene& saved, const std::filesystem::path& path) {
  WriteTextFileAtomically(path, SceneToJson(saved));
}

SavedScene ReadSceneJson(const std::filesystem::path& path) {
  return SceneFromJson(ReadTextFile(path, "scene file not found (run `omm mosaic` first)"),
                       path.string());
}

}  // namespace omm
