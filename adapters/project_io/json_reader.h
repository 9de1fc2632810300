// Reading and writing the project's JSON files (truth, saved scene) with
// nlohmann::json; private to adapters/project_io.
#pragma once

#include <string>
#include <utility>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "pipeline/core/error.h"

namespace omm {

inline nlohmann::json JsonArray(const Eigen::VectorXd& v) {
  nlohmann::json out = nlohmann::json::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) out.push_back(v[i]);
  return out;
}

// Every access names the key's path, so that a malformed file says where:
// InputError("<where> key 'tiles[3].adjusted_mm'", "expected 2 numbers").
class JsonReader {
 public:
  using json = nlohmann::json;

  explicit JsonReader(std::string where) : where_(std::move(where)) {}

  const json& At(const json& node, const std::string& key, const std::string& path) const {
    if (!node.is_object() || !node.contains(key)) Fail(path + "." + key, "missing");
    return node.at(key);
  }
  double Number(const json& node, const std::string& key, const std::string& path) const {
    const json& v = At(node, key, path);
    if (!v.is_number()) Fail(path + "." + key, "expected a number");
    return v.get<double>();
  }
  int Int(const json& node, const std::string& key, const std::string& path) const {
    const json& v = At(node, key, path);
    if (!v.is_number_integer()) Fail(path + "." + key, "expected an integer");
    return v.get<int>();
  }
  std::string String(const json& node, const std::string& key, const std::string& path) const {
    const json& v = At(node, key, path);
    if (!v.is_string()) Fail(path + "." + key, "expected a string");
    return v.get<std::string>();
  }
  const json& Array(const json& node, const std::string& key, const std::string& path) const {
    const json& v = At(node, key, path);
    if (!v.is_array()) Fail(path + "." + key, "expected an array");
    return v;
  }
  // An array of numbers; of exactly `size` numbers unless size < 0.
  Eigen::VectorXd Vector(const json& node, const std::string& key, const std::string& path,
                         int size = -1) const {
    const json& v = Array(node, key, path);
    if (size >= 0 && static_cast<int>(v.size()) != size) {
      Fail(path + "." + key, "expected " + std::to_string(size) + " numbers");
    }
    Eigen::VectorXd out(v.size());
    for (size_t i = 0; i < v.size(); ++i) {
      if (!v[i].is_number()) Fail(path + "." + key, "expected numbers");
      out[static_cast<Eigen::Index>(i)] = v[i].get<double>();
    }
    return out;
  }
  Eigen::Vector2d Vec2(const json& node, const std::string& key, const std::string& path) const {
    return Vector(node, key, path, 2);
  }
  [[noreturn]] void Fail(const std::string& key, const std::string& what) const {
    throw InputError(where_ + " key '" + key + "'", what);
  }

 private:
  std::string where_;
};

}  // namespace omm
