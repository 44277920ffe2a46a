#!/usr/bin/env python3
"""OpenCV's findChessboardCornersSB on the real chart photos, recorded for the Rust test.

    pip install opencv-python-headless numpy
    scripts/opencv_real_charts.py tests/data/real/charts

Reads DIR/SOURCES.md's photos (every *.jpg in DIR) with the board size of DIR/chart.json
(cols × rows squares, so (cols − 1) × (rows − 1) inner corners), runs
findChessboardCornersSB (flags ACCURACY | EXHAUSTIVE | NORMALIZE_IMAGE) on each photo
upright and turned by 90°, 180°, 270° (exact pixel permutations, as the Rust test makes
them) and writes DIR/opencv.json: per photo whether OpenCV found the board upright, its
inner corners there (x right, y down, pixel centres at integers: OpenCV's own
convention, the same as lensblur's) and whether it found it turned. Its format is in
docs/formats.md ("OpenCV's corners on the real chart photos").
"""

import glob
import json
import os
import sys

import cv2
import numpy as np

FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_NORMALIZE_IMAGE


def find(gray, inner):
    ok, corners = cv2.findChessboardCornersSB(gray, inner, FLAGS)
    return (corners.reshape(-1, 2).tolist() if ok else None)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    folder = sys.argv[1]
    chart = json.load(open(os.path.join(folder, "chart.json")))
    inner = (chart["cols"] - 1, chart["rows"] - 1)
    photos = []
    for path in sorted(glob.glob(os.path.join(folder, "*.jpg"))):
        gray = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if gray is None:
            sys.exit(f"{path}: not an image OpenCV reads")
        corners = find(gray, inner)
        turned = {}
        for quarter in (1, 2, 3):
            # np.rot90 turns counter-clockwise; the Rust test turns clockwise by
            # `quarter` quarter turns, which is np.rot90(k = -quarter).
            turned[str(90 * quarter)] = find(np.ascontiguousarray(np.rot90(gray, -quarter)), inner) is not None
        photos.append(
            {
                "file": os.path.basename(path),
                "width": int(gray.shape[1]),
                "height": int(gray.shape[0]),
                "found": corners is not None,
                "corners": corners or [],
                "found_turned": turned,
            }
        )
        print(f"{os.path.basename(path)}: {'found' if corners else 'not found'}, turned {turned}")
    out = {
        "schema": "lensblur.opencv-corners/1",
        "opencv": cv2.__version__,
        "function": "findChessboardCornersSB",
        "flags": "ACCURACY | EXHAUSTIVE | NORMALIZE_IMAGE",
        "inner_corners": list(inner),
        "photos": photos,
    }
    with open(os.path.join(folder, "opencv.json"), "w") as f:
        json.dump(out, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
