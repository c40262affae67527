"""The evidence behind the quasi-3D pinch kernel's transfer (docs/skin.md, "Mechanics"): the packaged kernel's
plane-strain channel table and two fresh solves of the intact skin (strip, plane strain; round probe,
axisymmetric) at the kernel's mesh.

1. Is each host measure monotone in depth at each offset (the precondition of a matched depth)?
2. The hypothesis behind any transfer: within plane strain, is A/A0 a single function of the host measure alone?
   The scatter: RMS and largest residual of the best monotone (isotonic) fit of A_ps against the measure, over
   every solved cell with the channel not yet shut (and the cells where it shuts first), to 4 mm deep.
3. The transfers at the comparison points of issue 22's independent estimate: matched depth (same offset) by the
   closing, the equivalent strain and the hole driver; matched offset (same depth) by the equivalent strain.

    python benchmarks/quasi3d_evidence.py
"""

from __future__ import annotations

import numpy as np
from sklearn.isotonic import IsotonicRegression

from neatskin.skin.kernel import packaged_kernel_path, read_kernel
from neatskin.skin.mechanics import solve_press
from neatskin.skin.quasi3d import area_at_depth, band_average, matched_depth

POINTS = ((0.0, 0.5, "0.56"), (0.0, 1.0, "< 0.05"), (4.0, 3.5, "0.14"), (5.0, 3.5, "0.72"), (6.0, 3.5, "0.92"))
POINTS += ((7.5, 3.5, "about 1.0"),)


def hosts(kernel):
    from neatskin.layout import load_layout
    from neatskin.skin.kernel import KernelSpec

    spec = KernelSpec.for_layout(load_layout("protocols/skins/paper.toml"))
    assert spec.key() == kernel.key, "the packaged kernel is not of the paper spec"
    out = {}
    for ax in (False, True):
        r = solve_press(spec.geometry, spec.material, spec.settings, 0.0, False, ax, bands_mm=spec.offsets_mm)
        closing = band_average(r.line_x_mm, r.closing_mm, spec.offsets_mm, spec.geometry.channel_width_mm, ax)
        out[ax] = {"closing": closing, "strain": r.strain_eq, "driver": -r.driver_tangential}
    return out


def scatter(area_ps, measure_ps, depths):
    """(rms, max) residual of the best non-increasing fit A = f(measure) over the open cells to 4 mm deep."""
    rows = []
    for i in range(area_ps.shape[0]):
        for j in np.flatnonzero(depths <= 4.0):
            a = area_ps[i, j]
            if np.isfinite(a) and np.isfinite(measure_ps[j, i]) and (a > 0 or area_ps[i, j - 1] > 0):
                rows.append((measure_ps[j, i], a))
    m, a = np.array(rows).T
    fit = IsotonicRegression(increasing=False).fit(m, a).predict(m)
    return float(np.sqrt(np.mean((a - fit) ** 2))), float(np.max(np.abs(a - fit))), m.size


def matched_offset(area_ps, m_ps, m_ax, offsets, depths, r, d):
    """Same depth, the offset r* >= where the strip's measure peaks at which it equals the round probe's at r."""
    j = int(np.argmin(np.abs(depths - d)))
    i = int(np.argmin(np.abs(offsets - r)))
    target, row = m_ax[j, i], m_ps[j]
    peak = int(np.argmax(row))
    tail_o, tail = offsets[peak:], row[peak:]
    if target >= tail[0]:
        r_star = tail_o[0]
    elif target <= tail[-1]:
        return 1.0, float("nan")
    else:
        r_star = float(np.interp(target, tail[::-1], tail_o[::-1]))
    k = min(int(r_star / (offsets[1] - offsets[0])), offsets.size - 2)
    t = (r_star - offsets[k]) / (offsets[1] - offsets[0])
    return float((1 - t) * area_ps[k, j] + t * area_ps[k + 1, j]), r_star


def main() -> None:
    kernel = read_kernel(packaged_kernel_path())
    offsets, depths = kernel.offsets_mm, kernel.depths_mm
    area_ps = kernel.extra["area_ratio_plane_strain"]
    h = hosts(kernel)
    print("1. monotone in depth (to 4 mm) at offsets 0..10 mm? offsets where not:")
    for name in ("closing", "strain", "driver"):
        for ax in (False, True):
            m = h[ax][name][depths <= 4.0]
            bad = [f"{o:g}" for i, o in enumerate(offsets) if np.any(np.diff(m[:, i]) < -1e-9)]
            print(f"   {name:8s} {'round' if ax else 'strip'}: {', '.join(bad) or 'none'}")
    print("2. within plane strain, A_ps as one non-increasing function of the measure: rms / max residual (cells)")
    for name in ("closing", "strain", "driver"):
        rms, worst, n = scatter(area_ps, h[False][name], depths)
        print(f"   {name:8s}: {rms:.3f} / {worst:.3f} ({n})")
    print("3. A/A0 at the estimate's points: matched depth (closing, strain, driver), matched offset (strain), strip")
    for r, d, estimate in POINTS:
        i = int(np.argmin(np.abs(offsets - r)))
        j = int(np.argmin(np.abs(depths - d)))
        row = []
        for name in ("closing", "strain", "driver"):
            d_star = matched_depth(h[False][name], h[True][name], depths)
            row.append(area_at_depth(area_ps, depths, d_star)[i, j])
        alt, r_star = matched_offset(area_ps, h[False]["strain"], h[True]["strain"], offsets, depths, r, d)
        cells = " ".join(f"{v:5.2f}" for v in row)
        print(
            f"   r {r:4.1f} d {d:3.1f}: {cells} | {alt:5.2f} (r* {r_star:4.1f}) | strip {area_ps[i, j]:5.2f} | "
            f"kernel {kernel.area_ratio[i, j]:5.2f} +- {kernel.extra['area_ratio_spread'][i, j]:4.2f} | "
            f"estimate {estimate}"
        )


if __name__ == "__main__":
    main()
