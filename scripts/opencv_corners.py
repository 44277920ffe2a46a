#!/usr/bin/env python3
"""Corner accuracy of OpenCV's findChessboardCornersSB beside lensblur's detect, on
simulated shots with exact ground truth.

    pip install opencv-python-headless numpy
    lensblur simulate --out DIR --width 2400 --height 1600 --focal 24,105 --aperture 4,10 --format png
    scripts/opencv_corners.py DIR [--lensblur target/release/lensblur]

For every 16-bit RGB shot in DIR (the simulator's *.png with its *.truth.json) this
prints, against the true corners: OpenCV's RMS corner error over the inner corners it
returns (flags ACCURACY | EXHAUSTIVE | NORMALIZE_IMAGE, on the linear image's luminance
at 16 bits scaled to 8), or that it failed; and lensblur's refined and bootstrap corner
RMS over every square it aligned (from `lensblur detect`). OpenCV reads no DNG, so the
comparison is on the RGB shots; the RAW figures of lensblur are in its tests.
"""

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile

import cv2
import numpy as np


def true_grid(truth):
    """Inner corners of the checkerboard as {(row, col): (x, y)}, from the squares'
    true corners (every square's top-left is grid point (row, col))."""
    pts = {}
    for sq in truth["squares"]:
        r, c = sq["row"], sq["col"]
        tl, tr, br, bl = sq["corners"]
        for (dr, dc), p in (((0, 0), tl), ((0, 1), tr), ((1, 1), br), ((1, 0), bl)):
            pts[(r + dr, c + dc)] = p
    return pts


def opencv_rms(png, truth, cols, rows):
    img = cv2.imread(png, cv2.IMREAD_UNCHANGED).astype(np.float64)
    lum = img[..., :3].mean(axis=2)
    gray = np.clip(lum / lum.max() * 255.0, 0, 255).astype(np.uint8)
    flags = (
        cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    ok, corners = cv2.findChessboardCornersSB(gray, (cols - 1, rows - 1), flags)
    if not ok:
        return None
    truth_pts = np.array(
        [p for (r, c), p in true_grid(truth).items() if 0 < r < rows and 0 < c < cols]
    )
    found = corners.reshape(-1, 2)
    # Each returned corner against its nearest true inner corner (the board's order and
    # orientation are OpenCV's own).
    d2 = ((found[:, None, :] - truth_pts[None, :, :]) ** 2).sum(axis=2).min(axis=1)
    return float(np.sqrt(d2.mean())), len(found)


def lensblur_rms(binary, png, truth, chart):
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "detect.json")
        cmd = [binary, "detect", png, "--out", out]
        if chart:
            cmd += ["--chart", chart]
        subprocess.run(cmd, check=True, capture_output=True)
        det = json.load(open(out))
    by_square = {(s["row"], s["col"]): s for s in truth["squares"]}
    e_ref, e_boot, n = 0.0, 0.0, 0
    for sq in det["squares"]:
        if sq.get("status", "ok") != "ok" or "corners" not in sq:
            continue
        t = by_square.get((sq["row"], sq["col"]))
        if t is None:
            continue
        for k in range(4):
            tx, ty = t["corners"][k]
            x, y = sq["corners"][k]
            e_ref += (x - tx) ** 2 + (y - ty) ** 2
            if "bootstrap_corners" in sq:
                bx, by = sq["bootstrap_corners"][k]
                e_boot += (bx - tx) ** 2 + (by - ty) ** 2
            n += 1
    return (e_ref / n) ** 0.5, (e_boot / n) ** 0.5, n // 4


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir")
    ap.add_argument("--lensblur", default="target/release/lensblur")
    ap.add_argument("--cols", type=int, default=24)
    ap.add_argument("--rows", type=int, default=16)
    ap.add_argument("--chart", help="chart.json when the shots are not of the default chart")
    args = ap.parse_args()
    shots = sorted(glob.glob(os.path.join(args.dir, "*.png")))
    if not shots:
        sys.exit(f"{args.dir}: no PNG shots")
    print("shot | σ (px) | OpenCV SB RMS | lensblur refined RMS | lensblur bootstrap RMS")
    for png in shots:
        truth = json.load(open(png[: -len(".png")] + ".truth.json"))
        sig = [g["sigma_x"] for s in truth["squares"] for _, g in s["pixel"]]
        cv = opencv_rms(png, truth, args.cols, args.rows)
        cv_txt = "failed" if cv is None else f"{cv[0]:.4f} px ({cv[1]} corners)"
        ref, boot, n = lensblur_rms(args.lensblur, png, truth, args.chart)
        print(
            f"{os.path.basename(png)} | {min(sig):.2f}–{max(sig):.2f} | {cv_txt} | "
            f"{ref:.4f} px ({n} squares) | {boot:.4f} px"
        )


if __name__ == "__main__":
    main()
