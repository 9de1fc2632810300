#include "adapters/mrcal/mrcal_problem.h"

#include <cassert>

#include <Eigen/Geometry>

// Only the cholmod_sparse struct is needed (mrcal_optimizer_callback fills one
// we own); nothing from libcholmod is called, so nothing is linked.
#include <suitesparse/cholmod.h>

namespace omm::mrcal_internal {
namespace {

Eigen::Vector3d MrcalOrigin(const BoardSpec& board) {
  return Eigen::Vector3d(0.5 * (board.cols - 1) * board.pitch_mm,
                         0.5 * (board.rows - 1) * board.pitch_mm, 0.0);
}

Eigen::Matrix3d RotationFromR(const Eigen::Vector3d& r) {
  const double angle = r.norm();
  if (angle < 1e-300) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, r / angle).toRotationMatrix();
}

int NumFrames(const Problem& p) { return static_cast<int>(p.frames_toref.size()); }
int NumObs(const Problem& p) { return static_cast<int>(p.observations.size()); }

}  // namespace

Vector6d RtMrcalFromOurs(const Vector6d& rt_cam_from_plate, const BoardSpec& board) {
  Vector6d rt = rt_cam_from_plate;
  rt.tail<3>() -= RotationFromR(rt.head<3>()) * MrcalOrigin(board);
  return rt;
}

Vector6d RtOursFromMrcal(const Vector6d& rt_cam_from_board, const BoardSpec& board) {
  Vector6d rt = rt_cam_from_board;
  rt.tail<3>() += RotationFromR(rt.head<3>()) * MrcalOrigin(board);
  return rt;
}

int Problem::NumStates() const {
  return mrcal_num_states(1, 0, NumFrames(*this), 0, 0, NumObs(*this), selections, &lensmodel);
}

int Problem::NumMeasurements() const {
  return mrcal_num_measurements(NumObs(*this), 0, width_n, height_n, 1, 0, NumFrames(*this), 0,
                                0, selections, &lensmodel);
}

int Problem::NumMeasurementsBoards() const {
  return mrcal_num_measurements_boards(NumObs(*this), width_n, height_n);
}

Problem ToProblem(const SolveRecord& record) {
  Problem p;
  const bool parsed = mrcal_lensmodel_from_name(&p.lensmodel, record.camera.lens_model.c_str());
  assert(parsed && mrcal_lensmodel_type_is_valid(p.lensmodel.type));
  (void)parsed;
  assert(record.camera.intrinsics.size() == mrcal_lensmodel_num_params(&p.lensmodel));
  p.intrinsics.assign(record.camera.intrinsics.data(),
                      record.camera.intrinsics.data() + record.camera.intrinsics.size());
  p.calobject_warp.x2 = record.calobject_warp.x();
  p.calobject_warp.y2 = record.calobject_warp.y();
  p.imagersize[0] = record.camera.width_px;
  p.imagersize[1] = record.camera.height_px;
  p.spacing_mm = record.board.pitch_mm;
  p.width_n = record.board.cols;
  p.height_n = record.board.rows;
  const int n_marks = p.width_n * p.height_n;
  for (size_t i = 0; i < record.images.size(); ++i) {
    const SolveImage& image = record.images[i];
    assert(image.q_px.cols() == n_marks && image.weight.size() == n_marks &&
           static_cast<int>(image.outlier.size()) == n_marks);
    const Vector6d rt = RtMrcalFromOurs(image.rt_cam_from_plate, record.board);
    mrcal_pose_t pose;
    for (int k = 0; k < 3; ++k) {
      pose.r.xyz[k] = rt[k];
      pose.t.xyz[k] = rt[3 + k];
    }
    p.frames_toref.push_back(pose);
    mrcal_observation_board_t observation;
    observation.icam.intrinsics = 0;
    observation.icam.extrinsics = -1;  // the camera is the reference
    observation.iframe = static_cast<int>(i);
    p.observations.push_back(observation);
    for (int m = 0; m < n_marks; ++m) {
      mrcal_point3_t q;
      q.x = image.q_px(0, m);
      q.y = image.q_px(1, m);
      q.z = (image.outlier[m] || image.weight[m] <= 0.0) ? -1.0 : image.weight[m];
      p.pool.push_back(q);
    }
  }
  p.selections = {};
  p.selections.do_optimize_intrinsics_core = record.problem.optimize_intrinsics_core;
  p.selections.do_optimize_intrinsics_distortions = record.problem.optimize_intrinsics_distortions;
  // No extrinsics exist (one camera at the reference); mrcal's python
  // uncertainty path requires the flag set, so keep the states identical.
  p.selections.do_optimize_extrinsics = true;
  p.selections.do_optimize_frames = record.problem.optimize_frames;
  p.selections.do_optimize_calobject_warp = record.problem.optimize_calobject_warp;
  p.selections.do_apply_regularization = record.problem.apply_regularization;
  p.selections.do_apply_outlier_rejection = record.problem.apply_outlier_rejection;
  // mrcal's python defaults; unused without discrete points.
  p.constants.point_min_range = -1.0;
  p.constants.point_max_range = -1.0;
  return p;
}

void UpdateRecord(const Problem& p, SolveRecord* record) {
  record->camera.intrinsics =
      Eigen::Map<const Eigen::VectorXd>(p.intrinsics.data(), p.intrinsics.size());
  record->calobject_warp = Eigen::Vector2d(p.calobject_warp.x2, p.calobject_warp.y2);
  const int n_marks = p.width_n * p.height_n;
  for (size_t i = 0; i < record->images.size(); ++i) {
    SolveImage& image = record->images[i];
    Vector6d rt;
    for (int k = 0; k < 3; ++k) {
      rt[k] = p.frames_toref[i].r.xyz[k];
      rt[3 + k] = p.frames_toref[i].t.xyz[k];
    }
    image.rt_cam_from_plate = RtOursFromMrcal(rt, record->board);
    for (int m = 0; m < n_marks; ++m) image.outlier[m] = p.pool[i * n_marks + m].z < 0.0;
  }
}

mrcal_stats_t Optimize(Problem* p, Eigen::VectorXd* x) {
  const int n_measurements = p->NumMeasurements();
  Eigen::VectorXd x_local(n_measurements);
  const mrcal_stats_t stats = mrcal_optimize(
      nullptr, 0, x_local.data(), n_measurements * static_cast<int>(sizeof(double)), p->intrinsics.data(), nullptr,
      p->frames_toref.data(), nullptr,
      p->selections.do_optimize_calobject_warp ? &p->calobject_warp : nullptr, 1, 0,
      NumFrames(*p), 0, 0, p->observations.data(), nullptr, NumObs(*p), 0, p->pool.data(),
      &p->lensmodel, p->imagersize, p->selections, &p->constants, p->spacing_mm, p->width_n,
      p->height_n, false, false);
  if (x) *x = x_local;
  return stats;
}

bool EvaluateCallback(const Problem& p, Eigen::VectorXd* x,
                      Eigen::SparseMatrix<double, Eigen::RowMajor>* J_packed) {
  const int n_state = p.NumStates();
  const int n_measurements = p.NumMeasurements();
  const int n_nonzero = _mrcal_num_j_nonzero(NumObs(p), 0, p.width_n, p.height_n, 1, 0,
                                             NumFrames(p), 0, 0, p.observations.data(), nullptr,
                                             p.selections, &p.lensmodel);
  // Jt is (Nstate x Nmeasurements) compressed-column, i.e. J compressed-row.
  std::vector<int> outer(n_measurements + 1);
  std::vector<int> inner(n_nonzero);
  std::vector<double> values(n_nonzero);
  cholmod_sparse Jt = {};
  Jt.nrow = n_state;
  Jt.ncol = n_measurements;
  Jt.nzmax = n_nonzero;
  Jt.p = outer.data();
  Jt.i = inner.data();
  Jt.x = values.data();
  Jt.stype = 0;
  Jt.itype = CHOLMOD_INT;
  Jt.xtype = CHOLMOD_REAL;
  Jt.dtype = CHOLMOD_DOUBLE;
  Jt.sorted = 1;
  Jt.packed = 1;
  std::vector<double> b_packed(n_state);
  x->resize(n_measurements);
  const bool ok = mrcal_optimizer_callback(
      b_packed.data(), n_state * static_cast<int>(sizeof(double)), x->data(),
      n_measurements * static_cast<int>(sizeof(double)),
      reinterpret_cast<cholmod_sparse_struct*>(&Jt), p.intrinsics.data(), nullptr,
      p.frames_toref.data(), nullptr,
      p.selections.do_optimize_calobject_warp ? &p.calobject_warp : nullptr, 1, 0, NumFrames(p),
      0, 0, p.observations.data(), nullptr, NumObs(p), 0, p.pool.data(), &p.lensmodel,
      p.imagersize, p.selections, &p.constants, p.spacing_mm, p.width_n, p.height_n, false);
  if (!ok) return false;
  const int nnz = outer[n_measurements];
  *J_packed = Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor>>(
      n_measurements, n_state, nnz, outer.data(), inner.data(), values.data());
  return true;
}

namespace {

// Where the optimised values sit in mrcal's state vector; < 0 if not
// optimised. One camera at the reference: no extrinsics, no points.
struct StateLayout {
  int intrinsics, first_intrinsic, num_intrinsics, frames, calobject_warp;
};

StateLayout Layout(const Problem& p) {
  StateLayout layout;
  const int n_frames = NumFrames(p), n_obs = NumObs(p);
  layout.intrinsics = mrcal_state_index_intrinsics(0, 1, 0, n_frames, 0, 0, n_obs, p.selections,
                                                   &p.lensmodel);
  layout.num_intrinsics = mrcal_num_states_intrinsics(1, p.selections, &p.lensmodel);
  // Every lens model here has a core (fx, fy, cx, cy) ahead of its other
  // parameters; the state holds the core only if it is optimised.
  layout.first_intrinsic = p.selections.do_optimize_intrinsics_core ? 0 : 4;
  layout.frames =
      mrcal_state_index_frames(0, 1, 0, n_frames, 0, 0, n_obs, p.selections, &p.lensmodel);
  layout.calobject_warp =
      mrcal_state_index_calobject_warp(1, 0, n_frames, 0, 0, n_obs, p.selections, &p.lensmodel);
  return layout;
}

}  // namespace

Eigen::VectorXd PackedState(const Problem& p) {
  const StateLayout layout = Layout(p);
  Eigen::VectorXd b(p.NumStates());
  if (layout.intrinsics >= 0) {
    for (int k = 0; k < layout.num_intrinsics; ++k) {
      b(layout.intrinsics + k) = p.intrinsics[layout.first_intrinsic + k];
    }
  }
  if (layout.frames >= 0) {
    for (int f = 0; f < NumFrames(p); ++f) {
      for (int k = 0; k < 3; ++k) {
        b(layout.frames + 6 * f + k) = p.frames_toref[f].r.xyz[k];
        b(layout.frames + 6 * f + 3 + k) = p.frames_toref[f].t.xyz[k];
      }
    }
  }
  if (layout.calobject_warp >= 0) {
    b(layout.calobject_warp) = p.calobject_warp.x2;
    b(layout.calobject_warp + 1) = p.calobject_warp.y2;
  }
  return b.cwiseQuotient(UnpackScale(p));
}

void SetPackedState(const Eigen::VectorXd& packed, Problem* p) {
  const StateLayout layout = Layout(*p);
  const Eigen::VectorXd b = packed.cwiseProduct(UnpackScale(*p));
  if (layout.intrinsics >= 0) {
    for (int k = 0; k < layout.num_intrinsics; ++k) {
      p->intrinsics[layout.first_intrinsic + k] = b(layout.intrinsics + k);
    }
  }
  if (layout.frames >= 0) {
    for (int f = 0; f < NumFrames(*p); ++f) {
      for (int k = 0; k < 3; ++k) {
        p->frames_toref[f].r.xyz[k] = b(layout.frames + 6 * f + k);
        p->frames_toref[f].t.xyz[k] = b(layout.frames + 6 * f + 3 + k);
      }
    }
  }
  if (layout.calobject_warp >= 0) {
    p->calobject_warp.x2 = b(layout.calobject_warp);
    p->calobject_warp.y2 = b(layout.calobject_warp + 1);
  }
}

GaussNewtonSummary ConvergeByGaussNewton(Problem* p) {
  GaussNewtonOptions options;
  options.step_tolerance = kMrcalUpdateThreshold;
  Problem trial = *p;
  Eigen::VectorXd state = PackedState(*p);
  const GaussNewtonSummary summary = MinimizeByGaussNewton(
      [&trial](const Eigen::VectorXd& s, Eigen::VectorXd* x,
               Eigen::SparseMatrix<double, Eigen::RowMajor>* J) {
        SetPackedState(s, &trial);
        return EvaluateCallback(trial, x, J);
      },
      options, &state);
  SetPackedState(state, p);
  return summary;
}

Eigen::VectorXd UnpackScale(const Problem& p) {
  Eigen::VectorXd d = Eigen::VectorXd::Ones(p.NumStates());
  mrcal_unpack_solver_state_vector(d.data(), 1, 0, NumFrames(p), 0, 0, p.selections,
                                   &p.lensmodel);
  return d;
}

}  // namespace omm::mrcal_internal
