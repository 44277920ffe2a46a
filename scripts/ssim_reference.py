#!/usr/bin/env python3
"""Reference SSIM/PSNR values for tests/suite/deblur.rs, from scikit-image.

The image pairs are the integer formulas of `lensblur::metrics::reference_pair`,
evaluated identically here. Run once; the printed numbers are pasted into the test.
    pip install scikit-image numpy
    python3 scripts/ssim_reference.py
"""
import numpy as np
from skimage.metrics import structural_similarity, peak_signal_noise_ratio


def pair(index, w, h):
    y, x = np.mgrid[0:h, 0:w]
    base = (x * 7 + y * 13 + (x * y) % 17) % 256
    if index == 0:
        v = (base + (x * 3 + y * 5) % 11) % 256
    elif index == 1:
        v = (base // 2 + 60 + (x ^ y) % 23) % 256
    else:
        v = (255 - base + (x * y) % 7) % 256
    return base.astype(np.float64) / 255.0, v.astype(np.float64) / 255.0


for index, w, h in [(0, 64, 48), (1, 50, 37), (2, 33, 29)]:
    a, b = pair(index, w, h)
    s = structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
                              use_sample_covariance=False, data_range=1.0)
    p = peak_signal_noise_ratio(a, b, data_range=1.0)
    print(f"({index}, {w}, {h}, {s:.12f}, {p:.12f}),")
