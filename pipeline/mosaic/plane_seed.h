// Initial values of the planar scene (pipeline/core/plane_scene.h) from the
// observations and the commanded table positions alone: no assumption on the
// camera's rotation about its axis, its tilt or its distance.
//
// Method: the plane-induced homography between tiles. With normalised rays
// m = (x, y, 1) (observations unprojected through the lens model) and
// H = [r1 r2 t] the plane's homography, a track seen in tiles i and j obeys
//     z_j m_j = z_i m_i + B dT,     B = [r1 r2] (3 x 2), dT = T_j - T_i,
// and the depth is z_i = 1 / (l . m_i) with l = n / delta, n = r3 the plane's
// normal and delta = n . t. Hence
//     m_j  ~  m_i + B dT (l . m_i)  =  m_i + K (dT (x) m_i),
// linear in the 18 entries of K = [B_1 l^T, B_2 l^T] (3 x 6). K is solved by
// linear least squares on m_j x (m_i + K (dT (x) m_i)) = 0 over all pairs (one
// reweighting pass drops pairs with an algebraic residual above 5x the
// median), then split into B and l by the best rank-1 approximation of its
// rearrangement vec(B) l^T, the scale fixed by |B_1| = |B_2| = 1 (B's columns
// are a rotation's) and the sign by l_3 > 0 (points in front). R is the
// rotation nearest [B, B_1 x B_2]. A strip (the table moved along one line
// u only) sees only b l^T, b = B u, 9 entries, solved alike (where all steps
// are equal, up to the family the scale of I + s K leaves: plane_seed.cc);
// then n = -l / |l| (the part frame's Z up, towards the camera: one motion
// cannot tell the frame's handedness) and r1, r2 from b and n. In both,
// delta = 1 / (n . l), t = (0, 0, delta / n_z)
// (the gauge kOriginOnOpticalAxis). Each track's P is the mean over its tiles
// of the ray's intersection with the plane, minus the commanded T_i; a
// plate's pose is the 2-D Procrustes fit of its marks' intersections (height
// as given, else 0; scale 1). Scale comes from the commanded motion, rotation
// about the axis and tilt from B, distance from the perspective in l.
#pragma once

#include <string>

#include "pipeline/core/camera.h"
#include "pipeline/core/plane_scene.h"

namespace omm {

struct PlaneSeedSummary {
  bool ok = false;
  std::string why_failed;  // set when !ok: "fewer than 20 track pairs", ...
  int num_pairs = 0;       // track pairs (same track, two tiles) used for K
  double rms_px = 0.0;     // reprojection RMS of the seeded scene
  double distance_mm = 0.0;  // |delta|: the camera centre's distance to the plane
  double tilt_deg = 0.0;
  // Angle between l and n (a strip: of b out of the plane), deg: ~0 for
  // consistent data, a quality check.
  double normal_disagreement_deg = 0.0;
};

// Fills *scene with initial values for SolvePlaneBundle (intrinsics: the
// camera's). Needs tracks seen in >= 2 tiles at different table positions.
// Failures are reported in the summary (scene then unusable).
PlaneSeedSummary SeedPlaneScene(const CameraModel& camera, const PlaneBundleInput& input,
                                PlaneScene* scene);

}  // namespace omm
