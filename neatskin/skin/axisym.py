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
        k_uu = self._in_plane_k_uu(FiT, pJ)
        # in-plane <-> hoop: dP_ij/dF3 = pJ / F3 FiT_ij, dP3/dF_kl = pJ / F3 FiT_kl
        cross = np.einsum("ijeq,aijeq->aeq", FiT * (pJ / F3 * self.dx), self.G)  # (12, el, q)
        k_uu += np.einsum("aeq,beq->abe", cross, self.hoop) + np.einsum("aeq,beq->abe", self.hoop, cross)
        k33 = (self.mu + self.mu / F3**2) * self.dx  # dP3/dF3
        k_uu += np.einsum("aeq,beq,eq->abe", self.hoop, self.hoop, k33)
        # pressure: dJ = J (FiT : dF + dF3 / F3)
        grad_j = np.einsum("ijeq,aijeq->aeq", FiT * J, self.G) + self.hoop * (J / F3)
        k_up = np.einsum("aeq,beq,eq->abe", grad_j, self.phi, self.dx)
        K = self._matrix(k_uu, self.udofs, self.udofs) + self._matrix(k_up, self.udofs, self.pdofs)
        return (K + self._matrix(np.swapaxes(k_up, 0, 1), self.pdofs, self.udofs) + self.Kpp).tocsr()

    def solid_area(self, x) -> float:
        return float(np.sum(self.kinematics(x)[1] * self.dx))
