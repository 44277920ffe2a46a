#!/usr/bin/env python3
"""LibRaw's reading of the real camera files in tests/data/real/, through rawpy: the
independent reader the RAW tests (tests/suite/real_files.rs) compare lensblur with.

Writes tests/data/real/libraw.tsv, one row per file:
  file, status, width, height, cfa, black (4, per CFA site in the order of cfa), white
status is `image` where LibRaw decodes a picture, `blank` where it decodes but 99 % or
more of the samples are one value (the file's image data is missing: LibRaw fills it
with zeros), or `refused` with LibRaw's error. width and height are LibRaw's visible
area (sizes.width/height), which is the active area lensblur measures.

    pip install rawpy && python3 scripts/libraw_reading.py
"""
import os
import sys

import numpy as np
import rawpy

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "real")


def reading(path):
    try:
        with rawpy.imread(path) as r:
            s = r.sizes
            if r.raw_type == rawpy.RawType.Flat:
                pixels = r.raw_image_visible
                desc = r.color_desc.decode()
                pat = r.raw_pattern
                cfa = "".join("RGBG"[pat[y % pat.shape[0]][x % pat.shape[1]]]
                              if desc == "RGBG" else desc[pat[y][x]]
                              for y in range(2) for x in range(2))
                cblack = list(r.black_level_per_channel)
                black = [cblack[pat[y][x]] for y in range(2) for x in range(2)]
                white = str(r.white_level)
                black = " ".join(str(b) for b in black)
            else:
                pixels = r.raw_image_visible if r.raw_image_visible.ndim == 3 else None
                if pixels is None:
                    pixels = r.postprocess(output_bps=16, gamma=(1, 1), no_auto_bright=True)
                cfa, black, white = "-", "-", "-"
            values, counts = np.unique(pixels, return_counts=True)
            status = "blank" if counts.max() >= 0.99 * pixels.size else "image"
            return [status, str(s.width), str(s.height), cfa, black, white]
    except Exception as e:  # LibRaw's refusal is the reading
        return ["refused: " + type(e).__name__, "-", "-", "-", "-", "-"]


def main():
    rows = [["file", "status", "width", "height", "cfa", "black", "white"]]
    for name in sorted(os.listdir(HERE)):
        if name.endswith((".md", ".tsv")):
            continue
        rows.append([name] + reading(os.path.join(HERE, name)))
    out = os.path.join(HERE, "libraw.tsv")
    with open(out, "w") as f:
        f.write("# LibRaw %s via rawpy %s (scripts/libraw_reading.py)\n"
                % (".".join(map(str, rawpy.libraw_version)), rawpy.__version__))
        for row in rows:
            f.write("\t".join(row) + "\n")
    print(open(out).read(), end="")


if __name__ == "__main__":
    sys.exit(main())
