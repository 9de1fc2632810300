#include "adapters/mrcal/cameramodel_io.h"

#include <cstdlib>
#include <memory>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_c.h"
#include "pipeline/core/error.h"

namespace omm {

void WriteCameraModel(const std::filesystem::path& path, const CameraModel& camera) {
  mrcal_lensmodel_t lensmodel;
  if (!mrcal_lensmodel_from_name(&lensmodel, camera.lens_model.c_str()) ||
      !mrcal_lensmodel_type_is_valid(lensmodel.type)) {
    throw InputError(path.string(), "cannot write lens model '" + camera.lens_model + "'");
  }
  const int n = mrcal_lensmodel_num_params(&lensmodel);
  if (camera.intrinsics.size() != n || camera.width_px <= 0 || camera.height_px <= 0) {
    throw InputError(path.string(), "camera has " + std::to_string(camera.intrinsics.size()) +
                                        " intrinsics for " + camera.lens_model + " (expected " +
                                        std::to_string(n) + ") or no imager size");
  }
  // mrcal_cameramodel_t ends in a flexible array of intrinsics.
  const size_t bytes = sizeof(mrcal_cameramodel_t) + n * sizeof(double);
  std::unique_ptr<void, decltype(&std::free)> buffer(std::calloc(1, bytes), &std::free);
  auto* model = static_cast<mrcal_cameramodel_t*>(buffer.get());
  model->imagersize[0] = static_cast<unsigned>(camera.width_px);
  model->imagersize[1] = static_cast<unsigned>(camera.height_px);
  model->lensmodel = lensmodel;
  for (int k = 0; k < n; ++k) model->intrinsics[k] = camera.intrinsics[k];
  if (!mrcal_write_cameramodel_file(path.c_str(), model)) {
    throw InputError(path.string(), "mrcal could not write the camera model");
  }
}

CameraModel ReadCameraModel(const std::filesystem::path& path) {
  mrcal_cameramodel_t* model = mrcal_read_cameramodel_file(path.c_str());
  if (model == nullptr) {
    throw InputError(path.string(), "not a readable mrcal .cameramodel file");
  }
  CameraModel camera;
  char name[1024];
  const bool named = mrcal_lensmodel_name(name, sizeof(name), &model->lensmodel);
  const int n = mrcal_lensmodel_num_params(&model->lensmodel);
  if (named) {
    camera.lens_model = name;
    camera.intrinsics = Eigen::Map<const Eigen::VectorXd>(model->intrinsics, n);
    camera.width_px = static_cast<int>(model->imagersize[0]);
    camera.height_px = static_cast<int>(model->imagersize[1]);
  }
  mrcal_free_cameramodel(&model);
  if (!named) throw InputError(path.string(), "mrcal cannot name the file's lens model");
  return camera;
}

}  // namespace omm
