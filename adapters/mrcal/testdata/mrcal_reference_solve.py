#!/usr/bin/python3
# Reference for uncertainty_test: python3-mrcal solves the same problem from the
# same seed and computes mrcal.projection_uncertainty; it also computes the
# uncertainty of OUR solve (no re-optimisation) to isolate that computation.
#   mrcal_reference_solve.py SEED_JSON OURS_JSON POINTS_JSON OUT_JSON
# SEED_JSON / OURS_JSON: omm solve records (adapters/mrcal/solve_record_json.h);
# POINTS_JSON: {"p_cam": [[x, y, z], ...]} (mm, camera frame);
# OUT_JSON: {"python_solve": {...}, "our_solve": {...}}, each with "intrinsics",
# "covariance" (N,2,2), "rms_px", "noutliers", "observed_sigma_px".
import json
import sys

import mrcal
import numpy as np


def optimization_inputs_from_record(record):
    board = record["board"]
    rows, cols, pitch = board["rows"], board["cols"], board["pitch_mm"]
    # omm's plate frame is centred; mrcal's starts at the first mark.
    origin = np.array(((cols - 1) / 2 * pitch, (rows - 1) / 2 * pitch, 0.0))
    frames, observations = [], []
    for image in record["images"]:
        rt = np.array(image["rt_cam_from_plate"], dtype=float)
        # p_cam = R (p_mrcal - o) + t
        rt_mrcal = mrcal.compose_rt(rt, np.concatenate((np.zeros(3), -origin)))
        frames.append(rt_mrcal)
        q = np.array(image["q_px"], dtype=float)
        w = np.array(image["weight"], dtype=float)
        w[np.array(image["outlier"], dtype=bool) | (w <= 0)] = -1.0
        observations.append(np.column_stack((q, w)).reshape(rows, cols, 3))
    camera = record["camera"]
    problem = record["problem"]
    n = len(frames)
    return dict(
        intrinsics=np.array(camera["intrinsics"], dtype=float)[np.newaxis, :],
        extrinsics_rt_fromref=np.zeros((0, 6), dtype=float),
        frames_rt_toref=np.array(frames),
        points=None,
        observations_board=np.array(observations),
        indices_frame_camintrinsics_camextrinsics=np.column_stack(
            (np.arange(n), np.zeros(n), -np.ones(n))).astype(np.int32),
        observations_point=None,
        indices_point_camintrinsics_camextrinsics=None,
        lensmodel=camera["lens_model"],
        imagersizes=np.array(((camera["width_px"], camera["height_px"]),), dtype=np.int32),
        calobject_warp=np.array(record["calobject_warp"], dtype=float)
        if problem["optimize_calobject_warp"] else None,
        do_optimize_intrinsics_core=problem["optimize_intrinsics_core"],
        do_optimize_intrinsics_distortions=problem["optimize_intrinsics_distortions"],
        do_optimize_extrinsics=True,
        do_optimize_frames=problem["optimize_frames"],
        do_optimize_calobject_warp=problem["optimize_calobject_warp"],
        calibration_object_spacing=pitch,
        do_apply_outlier_rejection=problem["apply_outlier_rejection"],
        do_apply_regularization=problem["apply_regularization"],
        verbose=False)


def uncertainty(optimization_inputs, p_cam):
    model = mrcal.cameramodel(optimization_inputs=optimization_inputs, icam_intrinsics=0)
    cov = mrcal.projection_uncertainty(p_cam, model=model, what="covariance")
    worst = mrcal.projection_uncertainty(p_cam, model=model, what="worstdirection-stdev")
    rms = mrcal.projection_uncertainty(p_cam, model=model, what="rms-stdev")
    x = mrcal.optimizer_callback(**optimization_inputs, no_jacobian=True,
                                 no_factorization=True)[1]
    residuals = mrcal.residuals_chessboard(optimization_inputs, residuals=x).ravel()
    return dict(intrinsics=optimization_inputs["intrinsics"][0].tolist(),
                covariance=cov.tolist(), worst_stdev_px=worst.tolist(),
                rms_stdev_px=rms.tolist(), observed_sigma_px=float(np.std(residuals)),
                noutliers=int(np.sum(optimization_inputs["observations_board"][..., 2] <= 0)))


seed = json.load(open(sys.argv[1]))
ours = json.load(open(sys.argv[2]))
p_cam = np.array(json.load(open(sys.argv[3]))["p_cam"], dtype=float)
final = ours["problem"]

# The staged solve of mrcal-calibrate-cameras from the same seed.
inputs = optimization_inputs_from_record(seed)
stages = ((False, False, False, False), (True, False, False, False),
          (True, True, final["apply_regularization"], False),
          (True, True, final["apply_regularization"], final["apply_outlier_rejection"]))
for core, distortions, regularization, outliers in stages:
    inputs.update(do_optimize_intrinsics_core=core, do_optimize_intrinsics_distortions=distortions,
                  do_apply_regularization=regularization, do_apply_outlier_rejection=outliers)
    if outliers and final["optimize_calobject_warp"]:
        inputs.update(do_optimize_calobject_warp=True, calobject_warp=np.zeros(2))
    stats = mrcal.optimize(**inputs)
python_solve = uncertainty(inputs, p_cam)
python_solve["rms_px"] = float(stats["rms_reproj_error__pixels"])

json.dump({"python_solve": python_solve,
           "our_solve": uncertainty(optimization_inputs_from_record(ours), p_cam)},
          open(sys.argv[4], "w"))
