// Progress of long work, reported by stages and shown by the program.
#pragma once

#include <functional>
#include <string>

namespace omm {

// Called as work advances: `done` of `total` steps of the task `what` (e.g.
// "rendering calib/calib_07.png"). May be empty; stages check before calling.
using ProgressCallback = std::function<void(int done, int total, const std::string& what)>;

}  // namespace omm
