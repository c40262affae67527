"""What the intact skin (no channel) does where a channel would be: per band centre x (the channel's width around
it, its height around its centre line), the mean equivalent strain, which the quasi-3D transfer (skin/quasi3d.py)
matches between the plane-strain strip and the axisymmetric round probe, and the hole driver (the linear estimate of a
channel's area change from the host's stress and strain there). (The closing across the channel's
height is sampled along lines by skin/mechanics.py and band-averaged by skin/quasi3d.py.)

The hole driver. A long cylindrical hole in a nearly incompressible solid under a uniform far field changes its
cross-section's area by dA/A = (s_11 + s_22) / (2 mu) - e_33 to first order, where 1, 2 span the cross-section
and 3 is the hole's axis (generalised plane strain: a uniform state with e_11 = e_22 = -e_33 / 2 and no in-plane
stress scales the hole by -e_33; the rest is Kirsch's plane-strain hole, dA/A = (S_11 + S_22)(kappa + 1) / (4 mu)
with kappa = 1). In plane strain e_33 = 0, so it is the in-plane mean stress over mu. For the round probe, a channel
running tangentially (its nearest point to the probe axis) has 3 = hoop: D = (s_rr + s_zz) / (2 mu) - ln F_33; one
running radially has 3 = r: D = (s_tt + s_zz) / (2 mu) - ln lambda_r. Cauchy stress, logarithmic axial strain."""

from __future__ import annotations

import numpy as np


class HostBands:
    """Bins an intact host's quadrature points into the channel-sized bands centred at `centres` (reference x)."""

    def __init__(self, ub, geometry, centres_mm: np.ndarray, axisymmetric: bool):
        g = geometry
        xq, yq = np.asarray(ub.global_coordinates())
        yc = (g.channel_floor_mm + g.channel_roof_mm) / 2
        inside = np.abs(yq - yc) <= g.channel_height_mm / 2 + 1e-9
        w = np.asarray(ub.dx) * inside  # cross-section area weights (not r-weighted: a channel's section)
        x = np.abs(xq) if axisymmetric else xq
        half = g.channel_width_mm / 2 + 1e-9
        self.weights = np.stack([w * (np.abs(x - c) <= half) for c in centres_mm])  # (bands, el, q)
        self.weights /= self.weights.sum(axis=(1, 2))[:, None, None]
        self.axisymmetric = axisymmetric

    def drivers(self, asm, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per band: the hole driver of a channel along the hoop (tangential) and along the radius, and the equivalent
        strain (what the quasi-3D transfer matches). The two drivers are equal in plane strain (no hoop: the channel
        runs along z)."""
        kin = asm.kinematics(x)
        F, J, p = kin[0], kin[1], kin[3]
        F3 = kin[4] if self.axisymmetric else np.ones_like(J)
        b = np.einsum("ikeq,jkeq->ijeq", F, F)  # in-plane left Cauchy-Green
        mu = asm.mu
        s_xx, s_yy = mu / J * (b[0, 0] - 1) + p, mu / J * (b[1, 1] - 1) + p
        s_33 = mu / J * (F3 * F3 - 1) + p
        tangential = (s_xx + s_yy) / (2 * mu) - np.log(F3)
        radial = (s_33 + s_yy) / (2 * mu) - 0.5 * np.log(b[0, 0]) if self.axisymmetric else tangential
        # the von Mises equivalent Hencky strain, from the in-plane principal stretches and the hoop one
        tr, det = b[0, 0] + b[1, 1], b[0, 0] * b[1, 1] - b[0, 1] * b[1, 0]
        disc = np.sqrt(np.maximum(tr * tr / 4 - det, 0.0))
        e = np.stack([0.5 * np.log(tr / 2 + disc), 0.5 * np.log(tr / 2 - disc), np.log(F3)])
        e = e - e.mean(axis=0)
        eq = np.sqrt(2.0 / 3.0 * np.sum(e * e, axis=0))
        avg = lambda v: np.einsum("beq,eq->b", self.weights, v)  # noqa: E731
        return avg(tangential), avg(radial), avg(eq)
