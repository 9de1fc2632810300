#!/usr/bin/python3
# Reference for cameramodel_io_test: load a .cameramodel with python3-mrcal and
# project camera-frame points through it.
#   project_with_mrcal.py MODEL POINTS_JSON OUT_JSON
# POINTS_JSON: {"p_cam": [[x, y, z], ...]}; OUT_JSON: {"q_px": [[x, y], ...],
# "lens_model": ..., "imagersize": [W, H], "valid_intrinsics_region": [[x, y],
# ...] or null}.
import json
import sys

import mrcal
import numpy as np

model = mrcal.cameramodel(sys.argv[1])
p = np.array(json.load(open(sys.argv[2]))["p_cam"], dtype=float)
lensmodel, intrinsics = model.intrinsics()
q = mrcal.project(p, lensmodel, intrinsics)
region = model.valid_intrinsics_region()
json.dump({"q_px": q.tolist(), "lens_model": lensmodel,
           "imagersize": [int(v) for v in model.imagersize()],
           "valid_intrinsics_region": None if region is None else region.tolist()},
          open(sys.argv[3], "w"))
