// TEMPORARY: stands in for omm_simulate_project until it is built.
#include <stdexcept>

#include "pipeline/simulate/simulate_project.h"

namespace omm {

std::string SimulationOptions::Check() const { return ""; }
std::vector<std::string> SimulationPresets() { return {"demo"}; }
std::filesystem::path DefaultTruthPath(const std::filesystem::path& project_dir) {
  return project_dir.string() + ".truth.json";
}
void SimulateProjectDirectory(const SimulationOptions&, const std::filesystem::path&,
                              const std::filesystem::path&, const ProgressCallback&) {
  throw std::runtime_error("the simulator is not linked yet");
}

}  // namespace omm
