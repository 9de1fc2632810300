#include "adapters/mrcal/solve_record_json.h"

#include <cerrno>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "adapters/mrcal/lens.h"
#include "pipeline/core/error.h"

namespace omm {
namespace {

using nlohmann::json;

constexpr const char* kFormat = "omm-solve-record";
constexpr int kVersion = 1;

json VectorToJson(const Eigen::VectorXd& v) { return std::vector<double>(v.data(), v.data() + v.size()); }

Eigen::VectorXd VectorFromJson(const json& j) {
  const std::vector<double> values = j.get<std::vector<double>>();
  return Eigen::Map<const Eigen::VectorXd>(values.data(), values.size());
}

BoardType BoardTypeFromName(const std::string& name, const std::string& where) {
  for (BoardType type : {BoardType::kCaltab, BoardType::kCircles, BoardType::kChessboard}) {
    if (name == BoardTypeName(type)) return type;
  }
  throw InputError(where, "key 'board.type': '" + name + "' is not caltab, circles or chessboard");
}

}  // namespace

std::string SolveRecordToJson(const SolveRecord& record) {
  json j;
  j["format"] = kFormat;
  j["version"] = kVersion;
  const BoardSpec& b = record.board;
  j["board"] = {{"type", BoardTypeName(b.type)}, {"rows", b.rows}, {"cols", b.cols},
                {"pitch_mm", b.pitch_mm}, {"dot_diameter_mm", b.dot_diameter_mm},
                {"frame_mm", b.frame_mm}, {"frame_bar_mm", b.frame_bar_mm},
                {"triangle_mm", b.triangle_mm}};
  j["camera"] = {{"lens_model", record.camera.lens_model},
                 {"intrinsics", VectorToJson(record.camera.intrinsics)},
                 {"width_px", record.camera.width_px},
                 {"height_px", record.camera.height_px}};
  j["calobject_warp"] = {record.calobject_warp.x(), record.calobject_warp.y()};
  const CalibrationProblem& p = record.problem;
  j["problem"] = {{"optimize_intrinsics_core", p.optimize_intrinsics_core},
                  {"optimize_intrinsics_distortions", p.optimize_intrinsics_distortions},
                  {"optimize_frames", p.optimize_frames},
                  {"optimize_calobject_warp", p.optimize_calobject_warp},
                  {"apply_regularization", p.apply_regularization},
                  {"apply_outlier_rejection", p.apply_outlier_rejection}};
  json images = json::array();
  for (const SolveImage& image : record.images) {
    json q = json::array();
    for (int m = 0; m < image.q_px.cols(); ++m) q.push_back({image.q_px(0, m), image.q_px(1, m)});
    images.push_back({{"image", image.image},
                      {"q_px", q},
                      {"weight", VectorToJson(image.weight)},
                      {"outlier", image.outlier},
                      {"rt_cam_from_plate", VectorToJson(image.rt_cam_from_plate)}});
  }
  j["images"] = images;
  return j.dump(1);
}

SolveRecord SolveRecordFromJson(const std::string& text, const std::string& where) {
  SolveRecord record;
  std::string key;  // the key being read, for the error message
  try {
    const json j = json::parse(text);
    key = "format";
    if (j.at("format").get<std::string>() != kFormat || j.at("version").get<int>() != kVersion) {
      throw InputError(where, std::string("not an ") + kFormat + " version " +
                                  std::to_string(kVersion));
    }
    key = "board";
    const json& b = j.at("board");
    record.board.type = BoardTypeFromName(b.at("type").get<std::string>(), where);
    record.board.rows = b.at("rows").get<int>();
    record.board.cols = b.at("cols").get<int>();
    record.board.pitch_mm = b.at("pitch_mm").get<double>();
    record.board.dot_diameter_mm = b.at("dot_diameter_mm").get<double>();
    record.board.frame_mm = b.at("frame_mm").get<double>();
    record.board.frame_bar_mm = b.at("frame_bar_mm").get<double>();
    record.board.triangle_mm = b.at("triangle_mm").get<double>();
    key = "camera";
    const json& c = j.at("camera");
    record.camera.lens_model = c.at("lens_model").get<std::string>();
    record.camera.intrinsics = VectorFromJson(c.at("intrinsics"));
    record.camera.width_px = c.at("width_px").get<int>();
    record.camera.height_px = c.at("height_px").get<int>();
    if (LensModelNumParams(record.camera.lens_model) !=
        static_cast<int>(record.camera.intrinsics.size())) {
      throw InputError(where, "key 'camera': lens model '" + record.camera.lens_model +
                                  "' does not match " +
                                  std::to_string(record.camera.intrinsics.size()) +
                                  " intrinsics");
    }
    key = "calobject_warp";
    const std::vector<double> warp = j.at("calobject_warp").get<std::vector<double>>();
    if (warp.size() != 2) throw InputError(where, "key 'calobject_warp': expected 2 numbers");
    record.calobject_warp = Eigen::Vector2d(warp[0], warp[1]);
    key = "problem";
    const json& p = j.at("problem");
    record.problem.optimize_intrinsics_core = p.at("optimize_intrinsics_core").get<bool>();
    record.problem.optimize_intrinsics_distortions =
        p.at("optimize_intrinsics_distortions").get<bool>();
    record.problem.optimize_frames = p.at("optimize_frames").get<bool>();
    record.problem.optimize_calobject_warp = p.at("optimize_calobject_warp").get<bool>();
    record.problem.apply_regularization = p.at("apply_regularization").get<bool>();
    record.problem.apply_outlier_rejection = p.at("apply_outlier_rejection").get<bool>();
    const int n_marks = record.board.rows * record.board.cols;
    for (const json& i : j.at("images")) {
      key = "images";
      SolveImage image;
      image.image = i.at("image").get<std::string>();
      key = "images[" + image.image + "]";
      const json& q = i.at("q_px");
      image.q_px.resize(2, static_cast<Eigen::Index>(q.size()));
      for (size_t m = 0; m < q.size(); ++m) {
        image.q_px(0, m) = q.at(m).at(0).get<double>();
        image.q_px(1, m) = q.at(m).at(1).get<double>();
      }
      image.weight = VectorFromJson(i.at("weight"));
      image.outlier = i.at("outlier").get<std::vector<bool>>();
      const Eigen::VectorXd rt = VectorFromJson(i.at("rt_cam_from_plate"));
      if (image.q_px.cols() != n_marks || image.weight.size() != n_marks ||
          static_cast<int>(image.outlier.size()) != n_marks || rt.size() != 6) {
        throw InputError(where, "key '" + key + "': expected " + std::to_string(n_marks) +
                                    " marks, weights and outlier flags and a 6-vector pose");
      }
      image.rt_cam_from_plate = rt;
      record.images.push_back(std::move(image));
    }
  } catch (const json::exception& e) {
    throw InputError(where, "key '" + key + "': " + e.what());
  }
  return record;
}

void WriteSolveRecord(const std::filesystem::path& path, const SolveRecord& record) {
  const std::string text = SolveRecordToJson(record);
  errno = 0;  // a failed write's reason (WriteError), not an earlier call's
  std::ofstream out(path);
  out << text << "\n";
  if (!out) throw WriteError(path, "cannot write the solve record");
}

SolveRecord ReadSolveRecord(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw InputError(path.string(), "cannot open the solve record");
  std::stringstream text;
  text << in.rdbuf();
  return SolveRecordFromJson(text.str(), path.string());
}

}  // namespace omm
