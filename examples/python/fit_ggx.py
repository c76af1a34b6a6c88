"""Fit an anisotropic GGX lobe to one point's exported samples with SciPy.

    refl export-samples runs/ward -o ward.npz
    python fit_ggx.py ward.npz COL ROW [MATERIAL_DIR]

The model is the one `refl` calls ggx_aniso (MATERIAL.md's microfacet form
with an analytic NDF):

    f(i, o) = kd / pi + ks D(h) F_rel(i . h) / (4 sigma(i) sigma(o))
    D(h) = 1 / (pi ax ay (hx^2/ax^2 + hy^2/ay^2 + hz^2)^2)   (lobe frame)
    sigma(v) = (vz + sqrt(vz^2 + vx^2 ax^2 + vy^2 ay^2)) / 2

with the lobe frame turned by `angle_rad` about the normal. The fit
minimises the weighted squared error of every channel (weights: each
channel's inverse variance, the export's `channel_weight`), starting from a generic lobe,
never from refl's answer. With MATERIAL_DIR, refl's own ggx_aniso fit of
that point (model_ggx_aniso.exr) is scored on the same samples beside it.
Prints one JSON object.
"""

import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from read_material import fresnel_relative, read_exr


def ggx_aniso(p, i, o):
    """f(i, o) per channel; p = kd(3), ks(3), alpha_x, alpha_y, angle_rad, eta."""
    kd, ks = p[0:3], p[3:6]
    ax, ay = np.clip(p[6], 1e-4, 4.0), np.clip(p[7], 1e-4, 4.0)
    angle, eta = p[8], np.clip(p[9], 1.01, 30.0)
    c, s = np.cos(-angle), np.sin(-angle)

    def lobe(v):
        return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], 1)

    h = i + o
    h /= np.linalg.norm(h, axis=1)[:, None]
    hl, il, ol = lobe(h), lobe(i), lobe(o)
    k = hl[:, 0] ** 2 / ax**2 + hl[:, 1] ** 2 / ay**2 + hl[:, 2] ** 2
    d = 1.0 / (np.pi * ax * ay * k * k)

    def sigma(v):
        r2 = (v[:, 0] * ax) ** 2 + (v[:, 1] * ay) ** 2
        return np.maximum(0.5 * (v[:, 2] + np.sqrt(v[:, 2] ** 2 + r2)), v[:, 2])

    spec = d * fresnel_relative(np.sum(i * h, axis=1), eta) / (4 * sigma(il) * sigma(ol))
    return kd[None, :] / np.pi + spec[:, None] * ks[None, :]


def point_samples(npz, col, row):
    """The usable samples of grid point (col, row): i, o, rho and each
    channel's weight."""
    d = np.load(npz)
    cols = int(d["grid"][0])
    where = np.nonzero(d["point"] == row * cols + col)[0]
    if where.size == 0:
        sys.exit(f"point {col},{row} was not exported (see --stride)")
    k = where[0]
    use = d["weight"][k] > 0
    w = d["channel_weight"][k]
    i = d["light"][k][use].astype(np.float64)
    o = np.broadcast_to(d["view"][k].astype(np.float64), i.shape)
    return i, o, d["rho"][k][use].astype(np.float64), w[use].astype(np.float64)


def chi2(p, i, o, rho, w):
    """Weighted squared error summed over samples and channels."""
    r = (ggx_aniso(p, i, o) - rho) * np.sqrt(w)
    return float(np.sum(r * r))


def fit(i, o, rho, w):
    # A generic start: the darkest tenth of the samples for the diffuse
    # level, a unit specular albedo, a medium isotropic lobe.
    lum = rho.mean(axis=1)
    kd0 = np.pi * rho[lum <= np.quantile(lum, 0.1)].mean(axis=0)
    best = None
    for angle in (0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4):
        p0 = np.concatenate([kd0, [1.0, 1.0, 1.0], [0.3, 0.3, angle, 1.5]])
        lo = [0, 0, 0, 0, 0, 0, 1e-3, 1e-3, -np.pi, 1.01]
        hi = [2, 2, 2, 50, 50, 50, 2.0, 2.0, 2 * np.pi, 5.0]
        r = least_squares(
            lambda p: ((ggx_aniso(p, i, o) - rho) * np.sqrt(w)).ravel(),
            p0,
            bounds=(lo, hi),
            x_scale="jac",
            max_nfev=400,
        )
        if best is None or r.cost < best.cost:
            best = r
    return best.x


def main():
    if len(sys.argv) not in (4, 5):
        sys.exit(__doc__)
    col, row = int(sys.argv[2]), int(sys.argv[3])
    i, o, rho, w = point_samples(sys.argv[1], col, row)
    p = fit(i, o, rho, w)
    names = ["kd_r", "kd_g", "kd_b", "ks_r", "ks_g", "ks_b", "alpha_x", "alpha_y", "angle_rad", "eta"]
    out = {"samples": int(len(w)), "scipy": {"params": dict(zip(names, map(float, p))), "chi2": chi2(p, i, o, rho, w)}}
    if len(sys.argv) == 5:
        m = Path(sys.argv[4])
        if (m / "material").is_dir():
            m = m / "material"
        ch = read_exr(m / "model_ggx_aniso.exr")
        q = np.array([float(ch[n][row, col]) for n in names])
        out["refl"] = {"params": dict(zip(names, map(float, q))), "chi2": chi2(q, i, o, rho, w)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
