#!/usr/bin/env python3
"""Reads a lensfun entry written by `lensblur lensfun` with lensfun itself (the C
library darktable and RawTherapee use, through ctypes) and checks what it does to a
held-out chart shot:

- loads the XML as a database and finds the camera and the lens by the shot's EXIF
  names (read by exiftool, not by lensblur);
- applies lensfun's own distortion and TCA correction to the shot's detected chart
  corners (`lensblur detect --out`), and reports the RMS residual of the corrected
  green corners to one homography (a straight chart) and the RMS distance of the red
  and blue corners from the green ones, before and after;
- applies lensfun's vignetting correction to a flat field (`lensblur simulate
  --flat-field`, a linear 16-bit grey PNG) and reports its spread in stops before
  and after.

Prints one JSON object. Needs python3, exiftool and lensfun's library (Debian:
liblensfun1); no other Python packages.

usage: lensfun_check.py --xml LENS.xml --shot SHOT.dng --detect DETECT.json
                        [--flat FLAT.png] [--lib liblensfun.so.1]
"""

import argparse
import ctypes
import json
import math
import struct
import subprocess
import sys
import zlib

LF_MODIFY_TCA = 0x01
LF_MODIFY_VIGNETTING = 0x02
LF_MODIFY_DISTORTION = 0x08
LF_PF_F32 = 3
LF_RECTILINEAR = 1
LF_CR_INTENSITY = 3


def fail(message):
    print(f"lensfun_check: {message}", file=sys.stderr)
    sys.exit(1)


def exif(path):
    out = subprocess.run(
        ["exiftool", "-j", "-n", "-Make", "-Model", "-LensModel", "-FocalLength",
         "-FNumber", "-ImageWidth", "-ImageHeight", path],
        check=True, capture_output=True, text=True).stdout
    return json.loads(out)[0]


def load_lensfun(lib):
    lf = ctypes.CDLL(lib)
    lf.lf_db_new.restype = ctypes.c_void_p
    lf.lf_db_load_file.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
    lf.lf_db_load_file.restype = ctypes.c_int
    lf.lf_db_find_cameras.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p]
    lf.lf_db_find_cameras.restype = ctypes.POINTER(ctypes.c_void_p)
    lf.lf_db_find_lenses_hd.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_char_p,
                                        ctypes.c_char_p, ctypes.c_int]
    lf.lf_db_find_lenses_hd.restype = ctypes.POINTER(ctypes.c_void_p)
    lf.lf_modifier_new.argtypes = [ctypes.c_void_p, ctypes.c_float, ctypes.c_int, ctypes.c_int]
    lf.lf_modifier_new.restype = ctypes.c_void_p
    lf.lf_modifier_initialize.argtypes = [
        ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int, ctypes.c_float, ctypes.c_float,
        ctypes.c_float, ctypes.c_float, ctypes.c_int, ctypes.c_int, ctypes.c_int]
    lf.lf_modifier_initialize.restype = ctypes.c_int
    lf.lf_modifier_apply_subpixel_geometry_distortion.argtypes = [
        ctypes.c_void_p, ctypes.c_float, ctypes.c_float, ctypes.c_int, ctypes.c_int,
        ctypes.POINTER(ctypes.c_float)]
    lf.lf_modifier_apply_subpixel_geometry_distortion.restype = ctypes.c_int
    lf.lf_modifier_apply_color_modification.argtypes = [
        ctypes.c_void_p, ctypes.c_void_p, ctypes.c_float, ctypes.c_float, ctypes.c_int,
        ctypes.c_int, ctypes.c_int, ctypes.c_int]
    lf.lf_modifier_apply_color_modification.restype = ctypes.c_int
    return lf


class LfCamera(ctypes.Structure):
    # lensfun 0.3's lfCamera: Maker, Model, Variant (multi-language strings), Mount, CropFactor.
    _fields_ = [("maker", ctypes.c_char_p), ("model", ctypes.c_char_p),
                ("variant", ctypes.c_char_p), ("mount", ctypes.c_char_p),
                ("crop_factor", ctypes.c_float)]


class LfLens(ctypes.Structure):
    _fields_ = [("maker", ctypes.c_char_p), ("model", ctypes.c_char_p)]


def solve(a, b):
    """Gaussian elimination with partial pivoting: a x = b."""
    n = len(b)
    m = [row[:] + [b[i]] for i, row in enumerate(a)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(m[r][c]))
        m[c], m[p] = m[p], m[c]
        for r in range(c + 1, n):
            f = m[r][c] / m[c][c]
            for k in range(c, n + 1):
                m[r][k] -= f * m[c][k]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        x[r] = (m[r][n] - sum(m[r][k] * x[k] for k in range(r + 1, n))) / m[r][r]
    return x


def homography_rms(chart, image):
    """RMS distance (px) of `image` points from the best homography of `chart` points:
    least squares in the linearised (DLT) form, then Gauss-Newton on the distances."""
    def project(h, p):
        w = h[6] * p[0] + h[7] * p[1] + 1.0
        return ((h[0] * p[0] + h[1] * p[1] + h[2]) / w, (h[3] * p[0] + h[4] * p[1] + h[5]) / w)

    ata = [[0.0] * 8 for _ in range(8)]
    atb = [0.0] * 8
    for (x, y), (u, v) in zip(chart, image):
        for row, rhs in (([x, y, 1, 0, 0, 0, -u * x, -u * y], u),
                         ([0, 0, 0, x, y, 1, -v * x, -v * y], v)):
            for i in range(8):
                atb[i] += row[i] * rhs
                for j in range(8):
                    ata[i][j] += row[i] * row[j]
    h = solve(ata, atb)
    for _ in range(5):
        ata = [[0.0] * 8 for _ in range(8)]
        atb = [0.0] * 8
        for (x, y), (u, v) in zip(chart, image):
            w = h[6] * x + h[7] * y + 1.0
            pu, pv = project(h, (x, y))
            ju = [x / w, y / w, 1 / w, 0, 0, 0, -pu * x / w, -pu * y / w]
            jv = [0, 0, 0, x / w, y / w, 1 / w, -pv * x / w, -pv * y / w]
            for row, r in ((ju, u - pu), (jv, v - pv)):
                for i in range(8):
                    atb[i] += row[i] * r
                    for j in range(8):
                        ata[i][j] += row[i] * row[j]
        step = solve(ata, atb)
        h = [a + b for a, b in zip(h, step)]
    ss = 0.0
    for p, (u, v) in zip(chart, image):
        pu, pv = project(h, p)
        ss += (u - pu) ** 2 + (v - pv) ** 2
    return math.sqrt(ss / len(chart))


def rms_distance(a, b):
    return math.sqrt(sum((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 for p, q in zip(a, b)) / len(a))


def apply_h(h, p):
    w = h[6] * p[0] + h[7] * p[1] + h[8]
    return ((h[0] * p[0] + h[1] * p[1] + h[2]) / w, (h[3] * p[0] + h[4] * p[1] + h[5]) / w)


def corrected(lf, mod, q, channel):
    """The corrected-image position whose `channel` (0 red, 1 green, 2 blue) lensfun
    samples at sensor point q: lensfun maps corrected to distorted, so invert it by
    fixed-point iteration (the map is the identity plus a small displacement)."""
    res = (ctypes.c_float * 6)()
    u = list(q)
    for _ in range(30):
        if not lf.lf_modifier_apply_subpixel_geometry_distortion(mod, u[0], u[1], 1, 1, res):
            fail("lensfun applied no distortion or TCA")
        d = (res[2 * channel], res[2 * channel + 1])
        u = [u[0] + q[0] - d[0], u[1] + q[1] - d[1]]
    return u


def read_png16_grey(path):
    """A 16-bit greyscale, non-interlaced PNG as rows of floats (0-1)."""
    data = open(path, "rb").read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        fail(f"{path}: not a PNG")
    pos, idat, width = 8, b"", 0
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth != 16 or colour != 0 or interlace != 0:
                fail(f"{path}: not a 16-bit grey PNG")
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw = zlib.decompress(idat)
    stride, bpp = width * 2, 2
    prev = bytearray(stride)
    rows = []
    for y in range(height):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            if f == 1:
                line[i] = (line[i] + a) & 255
            elif f == 2:
                line[i] = (line[i] + b) & 255
            elif f == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + pred) & 255
        rows.append([v / 65535.0 for v in struct.unpack(f">{width}H", bytes(line))])
        prev = line
    return width, height, rows


def spread_stops(values):
    v = sorted(values)
    lo, hi = v[len(v) // 200], v[-1 - len(v) // 200]
    return math.log2(hi / lo)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--xml", required=True)
    ap.add_argument("--shot", required=True)
    ap.add_argument("--detect", required=True)
    ap.add_argument("--flat")
    ap.add_argument("--lib", default="liblensfun.so.1")
    args = ap.parse_args()

    tags = exif(args.shot)
    for t in ("Make", "Model", "LensModel", "FocalLength", "FNumber"):
        if t not in tags:
            fail(f"{args.shot}: EXIF has no {t}")
    lf = load_lensfun(args.lib)
    db = lf.lf_db_new()
    err = lf.lf_db_load_file(db, args.xml.encode())
    if err != 0:
        fail(f"{args.xml}: lensfun could not load it (error {err})")
    cams = lf.lf_db_find_cameras(db, str(tags["Make"]).encode(), str(tags["Model"]).encode())
    if not cams or not cams[0]:
        fail(f"lensfun finds no camera '{tags['Make']} {tags['Model']}'")
    camera = LfCamera.from_address(cams[0])
    lenses = lf.lf_db_find_lenses_hd(db, cams[0], None, str(tags["LensModel"]).encode(), 0)
    if not lenses or not lenses[0]:
        fail(f"lensfun finds no lens '{tags['LensModel']}' for that camera")
    lens = LfLens.from_address(lenses[0])

    det = json.load(open(args.detect))
    width, height = det["width"], det["height"]
    mod = lf.lf_modifier_new(lenses[0], camera.crop_factor, width, height)
    wanted = LF_MODIFY_TCA | LF_MODIFY_DISTORTION | LF_MODIFY_VIGNETTING
    got = lf.lf_modifier_initialize(mod, lenses[0], LF_PF_F32, float(tags["FocalLength"]),
                                    float(tags["FNumber"]), 10.0, 1.0, LF_RECTILINEAR,
                                    wanted, 0)

    chart, green, red, blue = [], [], [], []
    for sq in det["squares"]:
        if sq["status"] != "ok":
            continue
        regs = {ch: h for ch, h in sq.get("channel_registration", [])}
        if not all(ch in regs for ch in ("R", "G", "B")):
            continue
        x, y = sq["col"], sq["row"]
        for c in ((x, y), (x + 1, y), (x + 1, y + 1), (x, y + 1)):
            chart.append(c)
            green.append(apply_h(regs["G"], c))
            red.append(apply_h(regs["R"], c))
            blue.append(apply_h(regs["B"], c))
    if len(chart) < 16:
        fail(f"{args.detect}: too few squares with per-channel registration")
    green_c = [corrected(lf, mod, q, 1) for q in green]
    red_c = [corrected(lf, mod, q, 0) for q in red]
    blue_c = [corrected(lf, mod, q, 2) for q in blue]
    report = {
        "camera": f"{tags['Make']} {tags['Model']}",
        "camera_found": camera.model.decode(),
        "crop_factor": round(camera.crop_factor, 4),
        "lens": tags["LensModel"],
        "lens_found": lens.model.decode(),
        "focal_mm": tags["FocalLength"],
        "f_number": tags["FNumber"],
        "corrections": {"distortion": bool(got & LF_MODIFY_DISTORTION),
                        "tca": bool(got & LF_MODIFY_TCA),
                        "vignetting": bool(got & LF_MODIFY_VIGNETTING)},
        "corners": len(chart),
        "straightness_rms_px": {"before": homography_rms(chart, green),
                                "after": homography_rms(chart, green_c)},
        "red_to_green_rms_px": {"before": rms_distance(red, green),
                                "after": rms_distance(red_c, green_c)},
        "blue_to_green_rms_px": {"before": rms_distance(blue, green),
                                 "after": rms_distance(blue_c, green_c)},
    }
    if args.flat:
        fw, fh, rows = read_png16_grey(args.flat)
        fmod = lf.lf_modifier_new(lenses[0], camera.crop_factor, fw, fh)
        lf.lf_modifier_initialize(fmod, lenses[0], LF_PF_F32, float(tags["FocalLength"]),
                                  float(tags["FNumber"]), 10.0, 1.0, LF_RECTILINEAR,
                                  LF_MODIFY_VIGNETTING, 0)
        before, after = [], []
        for y in range(0, fh, 4):
            row = (ctypes.c_float * fw)(*rows[y])
            before.extend(rows[y][::4])
            if not lf.lf_modifier_apply_color_modification(fmod, row, 0.0, float(y), fw, 1,
                                                           LF_CR_INTENSITY, fw * 4):
                fail("lensfun applied no vignetting correction")
            after.extend(row[::4])
        report["flat_field_spread_stops"] = {"before": spread_stops(before),
                                             "after": spread_stops(after)}
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
