"""The mixed neo-Hookean solid's residual and tangent on Taylor-Hood P2/P1 triangles (skin/mechanics.py's formulation),
its element blocks batched over every element and quadrature point, summed into a sparsity found once."""

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
    """Residual and tangent of the mixed neo-Hookean solid, each block computed at once over every element and
    quadrature point (the local basis gradients are fixed; only F and p change between Newton iterations).

    The tangent is the hot loop of a fine solve (one per Newton iteration): its element blocks are batched matrix
    products over (element, quadrature point), laid out (el, a, b), and the global matrix's sparsity, which the
    mesh fixes, is found once here: each tangent only sums the element blocks into its slots (np.bincount)."""

    def __init__(self, ub, pb, mu: float, bulk: float, dx=None):
        self.ub, self.pb, self.mu, self.bulk = ub, pb, mu, bulk
        self.G = np.stack([b[0].grad for b in ub.basis])  # (12, 2, 2, el, q)
        self.phi = np.stack([np.asarray(b[0]) for b in pb.basis])  # (3, el, q)
        self.dx = ub.dx if dx is None else dx  # (el, q): the integration weights (times r when axisymmetric)
        self.udofs, self.pdofs = ub.element_dofs, pb.element_dofs + ub.N
        n_basis, n_el, n_q = self.G.shape[0], self.G.shape[3], self.G.shape[4]
        # the gradients as (el, q, a, ij), ij = 2 i + j: a basis function's row of the 4 x 4 tangent moduli
        self.Gm = np.ascontiguousarray(self.G.reshape(n_basis, 4, n_el, n_q).transpose(2, 3, 0, 1))
        self.Gt = np.ascontiguousarray(self.Gm.transpose(0, 2, 1, 3).reshape(n_el, n_basis, 4 * n_q))
        self.phiT = np.ascontiguousarray(self.phi.transpose(1, 2, 0))  # (el, q, 3)
        mass = np.einsum("aeq,beq,eq->eab", self.phi, self.phi, self.dx)
        self.k_pp = -mass / bulk  # (el, 3, 3): constant
        self._pattern()

    def _pattern(self) -> None:
        """The global matrix's sparsity (CSR) and each element entry's slot in it, blocks in the order uu, up, pu, pp
        (each (el, a, b))."""
        n = self.ub.N + self.pb.N
        U, P = self.udofs.T, self.pdofs.T  # (el, 12), (el, 3)
        rows, cols = [], []
        for r, c in ((U, U), (U, P), (P, U), (P, P)):
            rows.append(np.broadcast_to(r[:, :, None], (r.shape[0], r.shape[1], c.shape[1])).ravel())
            cols.append(np.broadcast_to(c[:, None, :], (r.shape[0], r.shape[1], c.shape[1])).ravel())
        linear = np.concatenate(rows).astype(np.int64) * n + np.concatenate(cols)
        unique, self._slot = np.unique(linear, return_inverse=True)
        self._indices = (unique % n).astype(np.int32)
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(unique // n, minlength=n))]).astype(np.int32)

    def _assemble(self, k_uu: np.ndarray, k_up: np.ndarray) -> sp.csr_matrix:
        """The global tangent (CSR) from the element blocks k_uu (el, 12, 12) and k_up (el, 12, 3)."""
        n = self.ub.N + self.pb.N
        local = np.concatenate([k_uu.ravel(), k_up.ravel(), k_up.transpose(0, 2, 1).ravel(), self.k_pp.ravel()])
        data = np.bincount(self._slot, local, self._indices.size)
        K = sp.csr_matrix((data, self._indices.copy(), self._indptr.copy()), shape=(n, n))
        K.eliminate_zeros()  # as the sum of the blocks' matrices did: the LU sees the sparsity it saw before
        return K

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

    def _grad_dot(self, T) -> np.ndarray:
        """(el, q, a): G_a : T at every quadrature point, T (2, 2, el, q)."""
        vec = T.reshape(4, *T.shape[2:]).transpose(1, 2, 0)[..., None]  # (el, q, 4, 1)
        return (self.Gm @ vec)[..., 0]

    def _in_plane_k_uu(self, FiT, pJ):
        """The in-plane displacement block per element (el, a, b), from dP_ij = A_ijkl dF_kl with
        A_ijkl = mu d_ik d_jl + (mu - pJ) FiT_il FiT_kj + pJ FiT_ij FiT_kl (plane strain and axisymmetric alike)."""
        f = FiT.transpose(2, 3, 0, 1)  # (el, q, 2, 2)
        n_el, n_q = f.shape[:2]
        A = (self.mu - pJ)[..., None, None, None, None] * (
            f[..., :, None, None, :] * f.swapaxes(-1, -2)[..., None, :, :, None]
        )
        A += pJ[..., None, None, None, None] * (f[..., :, :, None, None] * f[..., None, None, :, :])
        A = A.reshape(n_el, n_q, 4, 4)
        A += self.mu * np.eye(4)
        A *= self.dx[..., None, None]
        GA = (self.Gm @ A).transpose(0, 2, 1, 3).reshape(n_el, -1, 4 * n_q)  # (el, a, q kl)
        return GA @ self.Gt.transpose(0, 2, 1)

    def tangent(self, x):
        F, J, FiT, p = self.kinematics(x)
        pJ = p * J
        k_uu = self._in_plane_k_uu(FiT, pJ)
        dj = self._grad_dot(FiT * (J * self.dx))  # (el, q, a)
        k_up = dj.transpose(0, 2, 1) @ self.phiT
        return self._assemble(k_uu, k_up)

    def solid_area(self, x) -> float:
        return float(np.sum(self.kinematics(x)[1] * self.dx))
