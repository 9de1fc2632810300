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

}  // namespace omm
