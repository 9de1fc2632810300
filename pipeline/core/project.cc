#include "pipeline/core/project.h"

namespace omm {

const char* FeatureTypeName(FeatureType type) {
  switch (type) {
    case FeatureType::kCircle: return "circle";
  }
  return "?";
}

const char* MeasurementTypeName(MeasurementType type) {
  switch (type) {
    case MeasurementType::kDistance: return "distance";
    case MeasurementType::kDiameter: return "diameter";
  }
  return "?";
}

LoadedImages WithoutDecodedImages(const LoadedImages& loaded, bool calib, bool tiles) {
  LoadedImages kept = loaded;
  if (calib)
    for (LoadedImage& image : kept.calib) image.image.reset();
  if (tiles)
    for (LoadedImage& image : kept.tiles) image.image.reset();
  return kept;
}

}  // namespace omm
