"""The Python examples against refl itself, on a simulated capture.

    python check_examples.py CAPTURE_DIR SAMPLES.npz REFL

1. read_material.py's evaluation of the tabulated model (from MATERIAL.md
   alone) against `refl brdf` at random directions, at points across the
   sample. Everything but sigma is the same arithmetic on the same stored
   values; sigma is integrated by each side its own way (refl's FFT table,
   interpolated; here a direct quadrature), which the bound allows for: 1%.
   A convention error (a flipped frame, a wrong ring layout, kd without
   1/pi) is tens of per cent.
2. fit_ggx.py's per-point SciPy fit against refl's ggx_aniso at the same
   points, on the exported samples. refl fits each cluster's lobe shape on
   a subset of its points and only the amplitudes per point, so a fit of
   the point alone, on the same weighted objective, must score at least as
   well; and its reduced chi-square must be near the noise model's 1
   (`tests/noise_model.rs` holds the model to the sensor within 5%), plus
   GGX's misfit to the true lobe, which is anisotropic Beckmann and which
   GGX matches only approximately: below 5. Exported directions or
   reflectances that disagree with what refl fitted would be orders of
   magnitude off; the luminance's weight applied to each channel (a
   Bayer sensor's channel is several times noisier than its luminance)
   gives about 7.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
EXAMPLES = HERE.parent.parent / "examples" / "python"
sys.path.insert(0, str(EXAMPLES))

from read_material import Material  # noqa: E402

failed = 0
passed = 0


def check(ok, what):
    global failed, passed
    print(("ok   " if ok else "FAIL ") + what)
    if ok:
        passed += 1
    else:
        failed += 1


def main():
    capture, npz, refl = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
    m = Material(capture)
    rng = np.random.default_rng(3)

    def dirs(n, zmin):
        z = rng.uniform(zmin, 1.0, n)
        p = rng.uniform(0, 2 * np.pi, n)
        s = np.sqrt(1 - z * z)
        return np.stack([s * np.cos(p), s * np.sin(p), z], 1)

    exported = np.load(npz)
    cols = int(exported["grid"][0])
    measured = [int(k) for k in exported["point"] if not m.flags.reshape(-1)[k] & 0x41]
    points = [measured[j] for j in np.linspace(0, len(measured) - 1, 4).astype(int)]
    for k in points:
        col, row = k % cols, k // cols
        i, o = dirs(300, 0.05), dirs(300, 0.2)
        lines = "".join(" ".join(f"{x:.9f}" for x in (*a, *b)) + "\n" for a, b in zip(i, o))
        out = subprocess.run(
            [refl, "brdf", str(capture), "--point", f"{col},{row}"], input=lines, capture_output=True, text=True
        )
        if out.returncode != 0:
            check(False, f"refl brdf at {col},{row}: {out.stderr}")
            continue
        theirs = np.loadtxt(out.stdout.splitlines())
        ours = m.tabulated(col, row).eval(i, o)
        rel = np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1e-6)
        check(rel.max() < 0.01, f"tabulated BRDF at {col},{row}: largest relative difference {rel.max():.2e}")

        fit = subprocess.run(
            [sys.executable, str(EXAMPLES / "fit_ggx.py"), npz, str(col), str(row), str(capture)],
            capture_output=True,
            text=True,
        )
        if fit.returncode != 0:
            check(False, f"fit_ggx.py at {col},{row}: {fit.stderr}")
            continue
        r = json.loads(fit.stdout)
        dof = 3 * r["samples"] - 10
        ours, theirs = r["scipy"]["chi2"], r["refl"]["chi2"]
        check(
            ours <= theirs * (1 + 1e-6),
            f"GGX at {col},{row}: SciPy's chi2 {ours:.1f} against refl's {theirs:.1f} ({r['samples']} samples)",
        )
        check(0 < dof and ours / dof < 5.0, f"GGX at {col},{row}: reduced chi2 {ours / max(dof, 1):.2f}")
        a, b = r["scipy"]["params"], r["refl"]["params"]
        print(
            f"     alphas SciPy {a['alpha_x']:.3f} {a['alpha_y']:.3f} at {np.degrees(a['angle_rad']):.1f} deg, "
            f"refl {b['alpha_x']:.3f} {b['alpha_y']:.3f} at {np.degrees(b['angle_rad']):.1f} deg"
        )
    print(f"python examples: {passed} passed, {failed} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
