"""The finite-element press: a flat probe pressed into the silicone across one fluid channel, solved with
scikit-fem in plane strain at large deformation; the channel's area ratio and the probe force per depth.

Formulation (docs/skin.md, "Mechanics"): mixed displacement-pressure (Taylor-Hood P2/P1 triangles, LBB-stable,
so the nearly incompressible solid neither locks nor shows pressure modes), strain energy per unit reference
area

    W(F, p) = mu/2 (I1 - 3) - mu ln J + p (J - 1) - p^2 / (2 K)      (plane strain: F33 = 1, I1 = tr F^T F + 1)

which is the compressible neo-Hookean solid with the pressure p = K (J - 1) as its own field. Newton's method
with the exact tangent, load stepping on the probe depth with step halving, and a backtracking line search
that refuses an inverted element (J <= 0). The channel's walls close through a node-to-node penalty contact
(the top wall's nodes against the bottom wall's at the same x), active-set updated every Newton iteration.
Units: mm, N, MPa (N/mm^2); forces are per mm of length along the channel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from neatskin.skin.feassembly import Assembler as _Assembler
from neatskin.skin.feassembly import dof_component
from neatskin.skin.fesetup import CLOSING_AREA_RATIO, SHUT_AREA_RATIO, Material, PressGeometry, SolverSettings

_FORM_ORDER = 4  # quadrature degree: exact for the P2 x P2 mass terms, ample for the nonlinear ones


@dataclass(frozen=True)
class PressResult:
    """One load-stepped press at one offset: per depth, the channel's area ratio and the probe force."""

    offset_mm: float
    depth_mm: np.ndarray  # (steps,)
    area_ratio: np.ndarray  # (steps,), deformed over reference channel area; nan past a failed step
    force_n_per_mm: np.ndarray  # (steps,), probe reaction per mm along the channel
    volume_change: np.ndarray  # (steps,), (solid area deformed - reference) / reference
    chord_force_n: np.ndarray  # (steps,), the reaction spread over the round probe's chords (quasi-3D)
    n_elements: int
    newton_iterations: int
    line_x_mm: np.ndarray | None = None  # without a channel: where the solid's closing is sampled
    closing_mm: np.ndarray | None = None  # (steps, points): u_y(roof line) - u_y(floor line), > 0 closing
    band_x_mm: np.ndarray | None = None  # without a channel: the centres of the channel-sized bands (skin/hostband.py)
    driver_tangential: np.ndarray | None = None  # (steps, bands): the hole driver of a channel along the hoop (z)
    driver_radial: np.ndarray | None = None  # (steps, bands): of one running radially (= tangential in plane strain)
    strain_eq: np.ndarray | None = None  # (steps, bands): von Mises equivalent Hencky strain (the transfer's measure)


def _lines(forced: list[float], lo: float, hi: float, fine_lo: float, fine_hi: float, h: float) -> np.ndarray:
    """Grid lines on [lo, hi]: spacing h on [fine_lo, fine_hi], growing by 1.4 per line outside it up to 4 h,
    through every forced coordinate."""
    fine_lo, fine_hi = max(fine_lo, lo), min(fine_hi, hi)  # a probe as wide as the skin: no lines beyond its ends
    inner = np.linspace(fine_lo, fine_hi, max(1, math.ceil((fine_hi - fine_lo) / h - 1e-9)) + 1)
    outer = []
    for edge, end, sign in ((fine_lo, lo, -1.0), (fine_hi, hi, 1.0)):
        x, step = edge, h
        while sign * (end - x) > 1e-9:
            step = min(step * 1.4, 4 * h)
            x = x + sign * step
            if sign * (end - x) < 0.5 * step:
                x = end
            outer.append(x)
    points = np.concatenate([inner, outer])
    forced_arr = np.asarray(sorted(set(forced)))
    keep = np.min(np.abs(points[:, None] - forced_arr[None, :]), axis=1) > 0.3 * h
    return np.unique(np.round(np.concatenate([points[keep], forced_arr]), 9))


def press_mesh(geometry: PressGeometry, offset_mm: float, element_mm: float, channel: bool = True):
    """A structured triangle mesh of the skin's cross-section with the channel cut out, grid lines through the
    channel walls and the probe edges; mirror-symmetric in x, mirrored for a negative offset."""
    from skfem import MeshTri

    g, h, o = geometry, element_mm, abs(offset_mm)
    a, hw = g.probe_radius_mm, g.channel_width_mm / 2
    forced_x = [-g.half_width_mm, g.half_width_mm, -hw, hw, 0.0, o - a, o + a]
    xs = _lines(forced_x, -g.half_width_mm, g.half_width_mm, -hw - 2.0, max(hw, o + a) + 2.0, h)
    if offset_mm < 0:
        xs = np.unique(-xs)
    floor, roof = g.channel_floor_mm, g.channel_roof_mm
    ys = _lines([0.0, floor, roof, g.thickness_mm], 0.0, g.thickness_mm, floor - 1.0, g.thickness_mm, h)
    nx, ny = xs.size, ys.size
    ii, jj = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    xc, yc = (xs[ii] + xs[ii + 1]) / 2, (ys[jj] + ys[jj + 1]) / 2
    solid = ~((np.abs(xc) < hw) & (yc > floor) & (yc < roof)) | (not channel)
    ii, jj, xc = ii[solid], jj[solid], xc[solid]
    n00, n10, n01, n11 = ii * ny + jj, (ii + 1) * ny + jj, ii * ny + jj + 1, (ii + 1) * ny + jj + 1
    right = xc >= 0  # diagonals mirrored about x = 0, so the mesh is its own mirror image
    tri = np.concatenate(
        [
            np.where(right, [n00, n10, n11], [n00, n10, n01]),
            np.where(right, [n00, n11, n01], [n10, n11, n01]),
        ],
        axis=1,
    )
    used, tri = np.unique(tri, return_inverse=True)
    tri = tri.reshape(3, -1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    points = np.vstack([X.ravel()[used], Y.ravel()[used]])
    return MeshTri(points, tri)


class _Problem:
    """The assembled pieces of one press: bases, boundary dofs, contact pairs and the channel's outline."""

    def __init__(
        self,
        geometry: PressGeometry,
        material: Material,
        settings: SolverSettings,
        offset_mm: float,
        channel: bool,
        axisymmetric: bool = False,
    ):
        from skfem import Basis, ElementTriP1, ElementTriP2, ElementVector

        g = geometry
        self.g, self.mat, self.settings, self.offset = g, material, settings, offset_mm
        self.mesh = press_mesh(g, offset_mm, settings.element_mm, channel)
        if axisymmetric:  # r >= 0 only: the triangles right of the axis (x = 0 is a grid line)
            keep = np.all(self.mesh.p[0, self.mesh.t] >= -1e-12, axis=0)
            used, t = np.unique(self.mesh.t[:, keep], return_inverse=True)
            self.mesh = type(self.mesh)(self.mesh.p[:, used], t.reshape(3, -1))
        self.ub = Basis(self.mesh, ElementVector(ElementTriP2()), intorder=_FORM_ORDER)
        self.pb = Basis(self.mesh, ElementTriP1(), intorder=_FORM_ORDER)
        self.nu, self.n = self.ub.N, self.ub.N + self.pb.N
        self.thickness = g.thickness_mm
        eps = 1e-7
        dx, dy = self.ub.doflocs
        self.comp = comp = dof_component(self.ub)
        top = np.isclose(dy, g.thickness_mm, atol=eps)
        under = top & (np.abs(dx - offset_mm) <= g.probe_radius_mm + eps)
        self.probe_y = np.flatnonzero(under & (comp == 1))
        # the bonded probe's rim is rounded: where the surface meets it, it is held at the rim's height
        rim = np.clip(
            (np.abs(dx[self.probe_y] - offset_mm) - (g.probe_radius_mm - settings.probe_edge_radius_mm)), 0, None
        )
        rim = np.minimum(rim / settings.probe_edge_radius_mm, 1.0)
        self.probe_lift_mm = settings.probe_edge_radius_mm * (1.0 - np.sqrt(1.0 - rim * rim))
        self.probe_chord_mm = 2 * np.sqrt(np.maximum(g.probe_radius_mm**2 - (dx[self.probe_y] - offset_mm) ** 2, 0.0))
        fixed = np.isclose(dy, 0.0, atol=eps) | under
        rollers = (np.abs(np.abs(dx) - g.half_width_mm) < eps) & (comp == 0)
        if axisymmetric:
            rollers |= (np.abs(dx) < eps) & (comp == 0)  # u_r = 0 on the axis
        self.dirichlet = np.flatnonzero(fixed | rollers)
        self.free = np.setdiff1d(np.arange(self.n), self.dirichlet)
        # contact: the channel roof's y-dofs against the floor's at the same x
        wall = (np.abs(dx) <= g.channel_width_mm / 2 + eps) & (comp == 1)
        roof = np.flatnonzero(wall & np.isclose(dy, g.channel_roof_mm, atol=eps))
        floor = np.flatnonzero(wall & np.isclose(dy, g.channel_floor_mm, atol=eps))
        roof, floor = roof[np.argsort(dx[roof])], floor[np.argsort(dx[floor])]
        # without a channel: the solid's closing across the channel's height, u_y(roof) - u_y(floor), along x
        # (the quasi-3D mapping compares it between the strip and the round probe; skin/kernel.py)
        line = comp == 1
        top_line = np.flatnonzero(line & np.isclose(dy, g.channel_roof_mm, atol=eps))
        bottom_line = np.flatnonzero(line & np.isclose(dy, g.channel_floor_mm, atol=eps))
        top_line, bottom_line = top_line[np.argsort(dx[top_line])], bottom_line[np.argsort(dx[bottom_line])]
        same = top_line.size == bottom_line.size and np.allclose(dx[top_line], dx[bottom_line])
        self.line_roof, self.line_floor = (top_line, bottom_line) if (same and not channel) else (roof[:0], roof[:0])
        self.line_x = dx[self.line_roof]
        if not channel:
            roof = floor = np.zeros(0, dtype=np.intp)
        if roof.size != floor.size or not np.allclose(dx[roof], dx[floor]):
            raise RuntimeError("the channel's roof and floor nodes do not pair up: the mesh is not structured")
        self.roof, self.floor = roof, floor
        self.gap0 = g.channel_height_mm
        self.penalty = settings.contact_penalty_ratio * material.shear_modulus_mpa
        self.outline = self._channel_outline() if channel else np.zeros((0, 2, 2), dtype=np.intp)
        self.area0 = self.channel_area(np.zeros(self.nu)) if channel else 0.0

    def _channel_outline(self) -> np.ndarray:
        """(segments, 2, 2) dof indices (start/end point, x/y) of the channel's boundary, counter-clockwise."""
        g, mesh, eps = self.g, self.mesh, 1e-7
        facets = mesh.boundary_facets()
        mid = mesh.p[:, mesh.facets[:, facets]].mean(axis=1)
        yc = (g.channel_floor_mm + g.channel_roof_mm) / 2
        on = (np.abs(mid[0]) <= g.channel_width_mm / 2 + eps) & (np.abs(mid[1] - yc) <= g.channel_height_mm / 2 + eps)
        segments = []
        for f in facets[on]:
            v0, v1 = mesh.facets[:, f]
            p0, p1 = mesh.p[:, v0] - [0.0, yc], mesh.p[:, v1] - [0.0, yc]
            if p0[0] * p1[1] - p0[1] * p1[0] < 0:
                v0, v1 = v1, v0
            d0, d1, dm = self.ub.nodal_dofs[:, v0], self.ub.nodal_dofs[:, v1], self.ub.facet_dofs[:, f]
            segments += [(d0, dm), (dm, d1)]
        return np.asarray(segments)

    def channel_area(self, u: np.ndarray) -> float:
        """The deformed channel's area (shoelace over its boundary's P2 nodes)."""
        x = self.ub.doflocs[self.comp, np.arange(self.nu)] + u
        s = self.outline
        return 0.5 * float(np.sum(x[s[:, 0, 0]] * x[s[:, 1, 1]] - x[s[:, 1, 0]] * x[s[:, 0, 1]]))


def solve_press(
    geometry: PressGeometry,
    material: Material,
    settings: SolverSettings,
    offset_mm: float,
    channel: bool = True,
    axisymmetric: bool = False,
    bands_mm: tuple[float, ...] | None = None,
) -> PressResult:
    """Load-step the probe at `offset_mm` from the channel axis down to settings.max_depth_mm.

    The channel counts as shut once its roof touches its floor across the whole width, or its area ratio falls
    below SHUT_AREA_RATIO, or Newton fails below CLOSING_AREA_RATIO (the walls folding into each other): its
    area ratio is then 0 at that depth and every deeper one (the load only grows), and the solve stops there.
    channel=False solves the skin without a channel; axisymmetric=True (channel False, offset 0) the round probe
    in (r, z), its force the total in N (`force_n_per_mm` and `chord_force_n` both hold it). Without a channel,
    `bands_mm` (band centres, mm from the probe axis) records the hole drivers of skin/hostband.py per depth."""
    if axisymmetric and (channel or offset_mm != 0):
        raise ValueError("the axisymmetric solve is of the skin without a channel, probe on the axis")
    if bands_mm is not None and channel:
        raise ValueError("band drivers are a property of the skin without a channel")
    pr = _Problem(geometry, material, settings, offset_mm, channel, axisymmetric)
    mu = material.shear_modulus_mpa
    if axisymmetric:
        from neatskin.skin.axisym import AxisymmetricAssembler

        asm: _Assembler = AxisymmetricAssembler(pr.ub, pr.pb, mu, material.bulk_ratio * mu)
    else:
        asm = _Assembler(pr.ub, pr.pb, mu, material.bulk_ratio * mu)
    nu = pr.nu
    bands = None
    if bands_mm is not None:
        from neatskin.skin.hostband import HostBands

        bands = HostBands(pr.ub, geometry, np.asarray(bands_mm, float), axisymmetric)
    area_solid = asm.solid_area(np.zeros(pr.n))
    tol = settings.newton_tol * mu * geometry.thickness_mm  # N/mm: the residual's natural size

    def residual(x):
        r = asm.residual(x)
        internal = r[:nu].copy()
        gap = pr.gap0 + x[pr.roof] - x[pr.floor]
        push = pr.penalty * np.minimum(gap, 0.0)
        r[pr.roof] += push
        r[pr.floor] -= push
        return r, internal, gap

    def tangent(x, gap):
        K = asm.tangent(x)
        active = gap < 0
        t, f, k = pr.roof[active], pr.floor[active], pr.penalty
        rows = np.concatenate([t, f, t, f])
        cols = np.concatenate([t, f, f, t])
        ones = np.ones(t.size)
        vals = k * np.concatenate([ones, ones, -ones, -ones])
        return K + sp.csr_matrix((vals, (rows, cols)), shape=K.shape)

    def newton(x, depth):
        x = x.copy()
        target = np.zeros(pr.n)
        target[pr.probe_y] = -np.maximum(depth - pr.probe_lift_mm, 0.0)
        step = np.zeros(pr.n)
        step[pr.dirichlet] = target[pr.dirichlet] - x[pr.dirichlet]
        for it in range(settings.max_newton):
            r, _, gap = residual(x)
            if not np.any(step) and np.max(np.abs(r[pr.free])) < tol:
                return x, it
            K = tangent(x, gap)
            rhs = -r - K @ step
            dx = step.copy()
            dx[pr.free] = _solve(K[pr.free][:, pr.free].tocsc(), rhs[pr.free])
            alpha = 1.0
            while asm.min_jacobian(x + alpha * dx) <= 0:
                alpha /= 2
                if alpha < 1e-3:
                    return None, it
            if alpha < 1.0 and np.any(step):
                return None, it  # the prescribed increment itself inverts an element: cut the load step
            x += alpha * dx
            step[:] = 0.0
        r, _, _ = residual(x)
        return (x if np.max(np.abs(r[pr.free])) < tol else None), settings.max_newton

    n_steps = int(round(settings.max_depth_mm / settings.depth_step_mm))
    depths = np.arange(n_steps + 1) * settings.depth_step_mm
    area, force, vol, chord = (np.full(depths.size, np.nan) for _ in range(4))
    closing = np.full((depths.size, pr.line_x.size), np.nan)
    closing[0] = 0.0
    n_bands = 0 if bands_mm is None else len(bands_mm)
    drivers = np.full((3, depths.size, n_bands), np.nan)
    drivers[:, 0] = 0.0
    area[0], force[0], vol[0], chord[0] = 1.0, 0.0, 0.0, 0.0
    x, reached, iterations, shut_at = np.zeros(pr.n), 0.0, 0, None
    for k, depth in enumerate(depths[1:], start=1):
        increment, halvings = depth - reached, 0
        while reached < depth - 1e-12:
            trial = min(depth, reached + increment)
            result, its = newton(x, trial)
            iterations += its
            if result is None:
                halvings += 1
                increment /= 2
                if halvings > settings.max_halvings:
                    break
                continue
            x, reached = result, trial
        ratio = pr.channel_area(x[:nu]) / pr.area0 if channel else np.nan
        gap = pr.gap0 + x[pr.roof] - x[pr.floor]
        if reached < depth - 1e-12:
            if channel and ratio < CLOSING_AREA_RATIO:
                shut_at = k
            break  # not shut: this depth and those below stay nan
        _, internal, _ = residual(x)
        reaction = -internal[pr.probe_y]  # the probe's downward push on each bonded node, N/mm
        force[k] = float(reaction.sum()) * (2 * np.pi if axisymmetric else 1.0)
        chord[k] = force[k] if axisymmetric else float(reaction @ pr.probe_chord_mm)
        vol[k] = asm.solid_area(x) / area_solid - 1.0
        closing[k] = x[pr.line_floor] - x[pr.line_roof]
        if bands is not None:
            drivers[:, k] = bands.drivers(asm, x)
        area[k] = ratio
        if channel and (bool(np.all(gap <= 0)) or ratio < SHUT_AREA_RATIO):
            shut_at = k + 1
            area[k] = 0.0
            break
    if shut_at is not None:
        area[shut_at:] = 0.0
    lines = (pr.line_x, closing) if pr.line_x.size else (None, None)
    band = (np.asarray(bands_mm, float), drivers[0], drivers[1], drivers[2]) if bands_mm is not None else (None,) * 4
    return PressResult(offset_mm, depths, area, force, vol, chord, pr.mesh.t.shape[1], iterations, *lines, *band)


def _solve(K, rhs):
    """K x = rhs on the free dofs: SuperLU with a symmetric ordering and no pivoting first (the saddle system is
    symmetric and its pressure block is -M / K, not 0), three times faster and sparser than the default; the
    pivoting LU where that one breaks down."""
    from scipy.sparse.linalg import splu

    try:
        x = splu(K, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True}, diag_pivot_thresh=0.0).solve(rhs)
        if np.all(np.isfinite(x)) and np.linalg.norm(K @ x - rhs) <= 1e-8 * float(np.linalg.norm(rhs)) + 1e-300:
            return x
    except RuntimeError:
        pass
    return spsolve(K, rhs)
