"""Read a reflectometer material and evaluate one point's BRDF.

Follows MATERIAL.md alone (maps.exr, ndf.exr, material.json), with the
OpenEXR and numpy packages:

    f(i, o) = kd / pi + ks D(h) F_rel(i . h) / (4 sigma(i) sigma(o))

D is the point's tabulated NDF, interpolated bilinearly between cell
centres in (sqrt(2 theta / pi), phi); sigma(v), the projected area of the
microsurface, is integrated here over the table's cells (D constant over
each); F_rel is the exact dielectric Fresnel term over its value at normal
incidence.

    python read_material.py MATERIAL_DIR COL ROW < directions

reads lines `ix iy iz ox oy oz` (unit directions toward the light and the
viewer, in the local frame) and prints `r g b` for each, as
`refl brdf MATERIAL_DIR --point COL,ROW` does.
"""

import json
import sys
from pathlib import Path

import numpy as np
import OpenEXR


def read_exr(path):
    """Every channel of a one-part EXR, as numpy arrays keyed by name."""
    with OpenEXR.File(str(path)) as f:
        return {name: np.array(ch.pixels) for name, ch in f.channels().items()}


def dielectric(cos_d, eta):
    """Exact unpolarised Fresnel reflectance of a dielectric of index eta."""
    c = np.clip(cos_d, 0.0, 1.0)
    sin2_t = (1.0 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    f = 0.5 * (rs * rs + rp * rp)
    return np.where(sin2_t >= 1.0, 1.0, np.clip(f, 0.0, 1.0))


def fresnel_relative(cos_d, eta):
    f0 = max(((eta - 1.0) / (eta + 1.0)) ** 2, 1e-6)
    return dielectric(cos_d, eta) / f0


class Table:
    """One point's tabulated NDF (rings of equal steps in sqrt(2 theta/pi))."""

    def __init__(self, values):
        self.d = np.asarray(values, dtype=np.float64)  # (n_theta, n_phi)
        self.n_theta, self.n_phi = self.d.shape
        t = np.arange(self.n_theta + 1) / self.n_theta
        self.theta_edges = t * t * np.pi / 2
        self.dphi = 2 * np.pi / self.n_phi
        # Quadrature for sigma: SUB x SUB points per cell, uniform in
        # (theta, phi), weighted by the solid angle sin(theta) dtheta dphi.
        sub = 12
        f = (np.arange(sub) + 0.5) / sub
        lo, hi = self.theta_edges[:-1], self.theta_edges[1:]
        theta = lo[:, None] + (hi - lo)[:, None] * f[None, :]  # (n_theta, sub)
        dtheta = ((hi - lo) / sub)[:, None]
        phi = (np.arange(self.n_phi)[:, None] + f[None, :]) * self.dphi  # (n_phi, sub)
        st = np.sin(theta)
        # Directions (n_theta, sub, n_phi, sub, 3) and weights.
        self.h = np.stack(
            np.broadcast_arrays(
                (st[:, :, None, None] * np.cos(phi)[None, None, :, :]),
                (st[:, :, None, None] * np.sin(phi)[None, None, :, :]),
                np.cos(theta)[:, :, None, None] * np.ones_like(phi)[None, None, :, :],
            ),
            axis=-1,
        ).reshape(-1, 3)
        w = (st * dtheta)[:, :, None, None] * (self.dphi / sub) * np.ones_like(phi)[None, None, :, :]
        cell = (np.arange(self.n_theta)[:, None, None, None] * self.n_phi + np.arange(self.n_phi)[None, None, :, None])
        cell = np.broadcast_to(cell, w.shape)
        self.qw = (w * self.d.reshape(-1)[cell]).reshape(-1)

    def eval(self, h):
        """Bilinear between cell centres, periodic in phi, clamped in theta."""
        theta = np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2]).clip(0.0, np.pi / 2)
        u = np.sqrt(theta / (np.pi / 2)) * self.n_theta
        phi = np.mod(np.arctan2(h[:, 1], h[:, 0]), 2 * np.pi) / self.dphi
        tu = np.clip(u - 0.5, 0.0, self.n_theta - 1)
        t0 = np.minimum(tu.astype(int), self.n_theta - 1)
        t1 = np.minimum(t0 + 1, self.n_theta - 1)
        ft = tu - t0
        pp = phi - 0.5
        pf = np.floor(pp)
        fp = pp - pf
        p0 = np.mod(pf.astype(int), self.n_phi)
        p1 = (p0 + 1) % self.n_phi
        a = self.d[t0, p0] * (1 - fp) + self.d[t0, p1] * fp
        b = self.d[t1, p0] * (1 - fp) + self.d[t1, p1] * fp
        return np.where(h[:, 2] > 0, a * (1 - ft) + b * ft, 0.0)

    def sigma(self, v):
        """Projected area toward each v, never below v.z."""
        s = np.clip(self.h @ v.T, 0.0, None).T @ self.qw
        return np.maximum(s, v[:, 2])


class Material:
    def __init__(self, path):
        path = Path(path)
        if (path / "material").is_dir():
            path = path / "material"
        self.meta = json.loads((path / "material.json").read_text())
        self.cols = self.meta["grid"]["cols"]
        self.rows = self.meta["grid"]["rows"]
        maps = read_exr(path / self.meta["maps"])
        self.kd, self.ks, self.eta = maps["kd"], maps["ks"], maps["eta"]
        self.flags = maps["flags"]
        ndf = self.meta["ndf"]
        g = ndf["grid"]
        d = read_exr(path / ndf["file"])["D"].astype(np.float64)
        self.tables = d.reshape(self.rows * self.cols, g["n_theta"], g["n_phi"])
        self.path = path

    def tabulated(self, col, row):
        return TabulatedBrdf(self, col, row)


class TabulatedBrdf:
    def __init__(self, m, col, row):
        self.kd = m.kd[row, col].astype(np.float64)
        self.ks = m.ks[row, col].astype(np.float64)
        self.eta = float(m.eta[row, col])
        self.table = Table(m.tables[row * m.cols + col])

    def eval(self, i, o):
        """f(i, o) per channel for arrays of unit directions (N, 3)."""
        i, o = np.atleast_2d(i).astype(np.float64), np.atleast_2d(o).astype(np.float64)
        above = (i[:, 2] > 0) & (o[:, 2] > 0)
        f = np.where(above[:, None], self.kd[None, :] / np.pi, 0.0)
        if self.ks.max() <= 0 or not (self.table.d.sum() > 0):
            return f
        h = i + o
        n = np.linalg.norm(h, axis=1)
        h = h / np.maximum(n, 1e-12)[:, None]
        d = self.table.eval(h)
        spec = d * fresnel_relative(np.sum(i * h, axis=1), self.eta)
        spec /= 4 * self.table.sigma(i) * self.table.sigma(o)
        return f + np.where(above & (n > 1e-6), 1.0, 0.0)[:, None] * spec[:, None] * self.ks[None, :]


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    m = Material(sys.argv[1])
    brdf = m.tabulated(int(sys.argv[2]), int(sys.argv[3]))
    rows = [list(map(float, line.split())) for line in sys.stdin if line.strip()]
    if not rows:
        return
    v = np.array(rows)
    for rgb in brdf.eval(v[:, :3], v[:, 3:6]):
        print(f"{rgb[0]:e} {rgb[1]:e} {rgb[2]:e}")


if __name__ == "__main__":
    main()
