"""The mixed neo-Hookean solid's residual and tangent on Taylor-Hood P2/P1 triangles (skin/mechanics.py's formulation),
assembled with one einsum per block over every element and quadrature point."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

_EYE = np.eye(2)[:, :, None, None]


def dof_component(ub) -> np.ndarray:
    """(ub.N,) 0 for each x (or r) displacement dof of a P2 vector basis, 1 for each y (or z) one."""
    comp = np.zeros(ub.N, dtype=np.intp)
    comp[ub.nodal_dofs[1]] = 1
    comp[ub.facet_dofs[1]] = 1
    return comp


class Assembler:
    """Residual and tangent of the mixed neo-Hookean solid, assembled with one einsum per block over every element
    and quadrature point (the local basis gradients are fixed; only F and p change between Newton iterations)."""

    def __init__(self, ub, pb, mu: float, bulk: float, dx=None):
        self.ub, self.pb, self.mu, self.bulk = ub, pb, mu, bulk
        self.G = np.stack([b[0].grad for b in ub.basis])  # (12, 2, 2, el, q)
        self.phi = np.stack([np.asarray(b[0]) for b in pb.basis])  # (3, el, q)
        self.dx = ub.dx if dx is None else dx  # (el, q): the integration weights (times r when axisymmetric)
        self.udofs, self.pdofs = ub.element_dofs, pb.element_dofs + ub.N
        mass = np.einsum("aeq,beq,eq->abe", self.phi, self.phi, self.dx)
        self.Kpp = self._matrix(-mass / bulk, self.pdofs, self.pdofs)

    def _matrix(self, local, rows, cols):
        n = self.ub.N + self.pb.N
        r = np.broadcast_to(rows[:, None, :], local.shape).ravel()
        c = np.broadcast_to(cols[None, :, :], local.shape).ravel()
        return sp.coo_matrix((local.ravel(), (r, c)), shape=(n, n))

    def kinematics(self, x):
        F = np.einsum("aijeq,ae->ijeq", self.G, x[self.udofs]) + _EYE
        J = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
        FiT = np.stack([np.stack([F[1, 1], -F[1, 0]]), np.stack([-F[0, 1], F[0, 0]])]) / J
        p = np.einsum("beq,be->eq", self.phi, x[self.pdofs])
        return F, J, FiT, p

    def min_jacobian(self, x) -> float:
        return float(self.kinematics(x)[1].min())

    def residual(self, x) -> np.ndarray:
        F, J, FiT, p = self.kinematics(x)
        P = self.mu * (F - FiT) + p * J * FiT
        r_u = np.einsum("ijeq,aijeq,eq->ae", P, self.G, self.dx)
        r_p = np.einsum("eq,beq,eq->be", J - 1.0 - p / self.bulk, self.phi, self.dx)
        n = self.ub.N + self.pb.N
        return np.bincount(self.udofs.ravel(), r_u.ravel(), n) + np.bincount(self.pdofs.ravel(), r_p.ravel(), n)

    def _in_plane_k_uu(self, FiT, pJ):
        """The in-plane displacement block per element, from dP_ij = A_ijkl dF_kl with
        A_ijkl = mu d_ik d_jl + (mu - pJ) FiT_il FiT_kj + pJ FiT_ij FiT_kl (plane strain and axisymmetric alike)."""
        eye = np.eye(2)
        A = self.mu * np.einsum("ik,jl->ijkl", eye, eye)[..., None, None] + (self.mu - pJ) * np.einsum(
            "ileq,kjeq->ijkleq", FiT, FiT
        )
        A += pJ * np.einsum("ijeq,kleq->ijkleq", FiT, FiT)
        AG = np.einsum("ijkleq,bkleq->ijbeq", A * self.dx, self.G, optimize=True)
        return np.einsum("aijeq,ijbeq->abe", self.G, AG)

    def tangent(self, x):
        F, J, FiT, p = self.kinematics(x)
        pJ = p * J
        k_uu = self._in_plane_k_uu(FiT, pJ)
        k_up = np.einsum("ijeq,aijeq,beq->abe", FiT * (J * self.dx), self.G, self.phi, optimize=True)
        K = self._matrix(k_uu, self.udofs, self.udofs) + self._matrix(k_up, self.udofs, self.pdofs)
        return (K + self._matrix(np.swapaxes(k_up, 0, 1), self.pdofs, self.udofs) + self.Kpp).tocsr()

    def solid_area(self, x) -> float:
        return float(np.sum(self.kinematics(x)[1] * self.dx))
