"""The round probe as an axisymmetric solve of the skin without a channel: the same mixed neo-Hookean solid as
skin/mechanics.py in (r, z) with the hoop stretch F33 = 1 + u_r / r, every integral weighted by r; it gives the
round flat probe's force in 3D (`solve_press(..., axisymmetric=True)`)."""

from __future__ import annotations

import numpy as np

from neatskin.skin.feassembly import Assembler as _Assembler


class AxisymmetricAssembler(_Assembler):
    """Residual and tangent with the hoop term. W = mu/2 (tr F^T F + F3^2 - 3) - mu ln J + p (J - 1) - p^2 / (2K),
    J = det(F) F3; P = mu F - mu F^-T + p J F^-T (in-plane), P3 = mu F3 - mu / F3 + p J / F3 (hoop)."""

    def __init__(self, ub, pb, mu: float, bulk: float):
        self.radius = np.asarray(ub.global_coordinates())[0]  # (el, q), > 0 at every quadrature point
        self.hoop = np.stack([np.asarray(b[0])[0] for b in ub.basis]) / self.radius  # (12, el, q): d F3 / d u_a
        ub_dx = ub.dx * self.radius
        super().__init__(ub, pb, mu, bulk, dx=ub_dx)
        self.hoopT = np.ascontiguousarray(self.hoop.transpose(1, 2, 0))  # (el, q, 12)

    def kinematics(self, x):
        F, J2, FiT, p = super().kinematics(x)
        F3 = 1.0 + np.einsum("aeq,ae->eq", self.hoop, x[self.udofs])
        return F, J2 * F3, FiT, p, F3

    def min_jacobian(self, x) -> float:
        return float(self.kinematics(x)[1].min())

    def residual(self, x) -> np.ndarray:
        F, J, FiT, p, F3 = self.kinematics(x)
        P = self.mu * (F - FiT) + p * J * FiT
        P3 = self.mu * (F3 - 1.0 / F3) + p * J / F3
        r_u = np.einsum("ijeq,aijeq,eq->ae", P, self.G, self.dx) + np.einsum("eq,aeq,eq->ae", P3, self.hoop, self.dx)
        r_p = np.einsum("eq,beq,eq->be", J - 1.0 - p / self.bulk, self.phi, self.dx)
        n = self.ub.N + self.pb.N
        return np.bincount(self.udofs.ravel(), r_u.ravel(), n) + np.bincount(self.pdofs.ravel(), r_p.ravel(), n)

    def tangent(self, x):
        F, J, FiT, p, F3 = self.kinematics(x)
        pJ = p * J
        k_uu = self._in_plane_k_uu(FiT, pJ)  # (el, a, b)
        hoop = self.hoopT  # (el, q, a)
        # in-plane <-> hoop: dP_ij/dF3 = pJ / F3 FiT_ij, dP3/dF_kl = pJ / F3 FiT_kl
        cross = self._grad_dot(FiT * (pJ / F3 * self.dx))  # (el, q, a)
        k_uu += cross.transpose(0, 2, 1) @ hoop + hoop.transpose(0, 2, 1) @ cross
        k33 = (self.mu + self.mu / F3**2) * self.dx  # dP3/dF3
        k_uu += (hoop * k33[..., None]).transpose(0, 2, 1) @ hoop
        # pressure: dJ = J (FiT : dF + dF3 / F3)
        grad_j = self._grad_dot(FiT * J) + hoop * (J / F3)[..., None]
        k_up = (grad_j * self.dx[..., None]).transpose(0, 2, 1) @ self.phiT
        return self._assemble(k_uu, k_up)

    def solid_area(self, x) -> float:
        return float(np.sum(self.kinematics(x)[1] * self.dx))
