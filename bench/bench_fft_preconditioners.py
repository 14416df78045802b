"""Preconditioners for the displacement form of the rotated scheme on a void foam: iteration counts.

The cell problem ``K u = b`` (``K = Bᵀ C B``, trilinear voxels with one-point quadrature, zero-stiffness void; see
``homogenization._nodal``) is solved by preconditioned CG to ``tol`` for load cases ``--cases`` with:

``green``
    ``M⁻¹ = K_I⁻¹`` (``K_I = Bᵀ B``, diagonal in Fourier space): what ``scheme="pcg"`` (and, mapped by ``B``,
    ``scheme="cg"``) does.
``green-jacobi``
    ``M⁻¹ = S K_I⁻¹ S`` with ``S = (diag K_I / diag K)^½`` per node and component (0 where ``diag K = 0``): the
    Green–Jacobi preconditioner of Ladecký, Pultarová, Bignonnet, Jödicke, Zeman, Pastewka (2025).
``green-hom``
    ``M⁻¹ = K_0⁻¹`` with ``K_0 = Bᵀ C_0 B`` for the reference ``C_0`` = the foam's homogenized stiffness (from a
    ``pcg`` solve): an anisotropic reference medium, still diagonal (3×3 blocks) in Fourier space.
``two-grid-F``, ``two-grid-hg-F``
    Green with an exact coarse-grid correction (balancing form ``(I − QK) K_I⁻¹ (I − KQ) + Q``,
    ``Q = P (Pᵀ K P)⁻¹ Pᵀ``) on the trilinear interpolation ``P`` from a grid ``F`` times coarser, optionally
    enriched by the four hourglass sign patterns (``hg``); the coarse matrix is assembled and factorized
    (scipy), which limits this to small N.
``local-hg-F``
    Green plus a local hourglass correction: ``K_I⁻¹ + Σ_c P_c (P_cᵀ K P_c)⁺ P_cᵀ``, one 12×12 block per node
    ``c`` of the grid ``F`` times coarser, ``P_c`` its four hourglass-signed trilinear functions × 3
    components (block Jacobi on the ``hg`` coarse space: no coarse solve, cheap to apply).

Each row reports the iterations and the stopping value, the **equilibrium residual of the final iterate in the
Green norm** ``‖r‖_{K_I⁻¹}/‖r_0‖_{K_I⁻¹}`` (= ``‖G[σ]‖/‖G[C:E]‖``, the stopping criterion of ``pcg``, so the
rows are comparable whatever the preconditioner's own norm) and ``C_JJ``. ``--ritz`` also prints the smallest
Ritz values of the Green-preconditioned operator (from the CG coefficients of the ``green`` runs).
``--only NAME ...`` runs the named rows only.

``--reuse METHOD ...`` runs instead the six unit load cases of the RVE (one operator, six right-hand sides) and
counts the K applications in all: ``sequential`` (one Green PCG after the other: what ``pcg`` does), ``block``
(block PCG on the six together, K-orthonormalized directions, converged columns leave the block), ``init`` and
``balanced`` (eigCG-type harvesting of ``--nev`` smallest eigenpairs per solve in a window of ``--window`` Lanczos
vectors, accumulated over the solves and deflating the later ones: in the initial guess only, or in every
iteration); it reports the stored nodal vectors and C against the sequential row, and writes
``DIR/bench_fft_preconditioners_reuse.csv``.
Usage: ``python bench/bench_fft_preconditioners.py --out out/bench [--n 32] [--gamma 1]``; writes
``DIR/bench_fft_preconditioners.csv``.
"""

from foambase.threads import single_threaded_blas_by_default

single_threaded_blas_by_default()  # before numpy loads OpenBLAS: its threads spin against FFTW's

import argparse  # noqa: E402
import csv  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spl  # noqa: E402

from foambase.files import atomic_open  # noqa: E402
from homogenization import _nodal  # noqa: E402
from homogenization.fft import homogenize_fft  # noqa: E402
from homogenization.tensors import isotropic_voigt, voigt_to_mandel  # noqa: E402

PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


class Problem:
    """K p and K_I⁻¹ r from the solver's own kernels (homogenization._nodal), on flat nodal vectors."""

    def __init__(self, phases, stiffness_mandel):
        self.phases, self.shape = phases, phases.shape
        tables = _nodal.stiffness_tables({int(p): stiffness_mandel[p] for p in np.unique(phases)})
        self.stiffness = stiffness_mandel
        self.ws = _nodal.NodalWorkspace(phases, tables, self.shape, (1.0, 1.0, 1.0), 1, False)

    def apply(self, u, E=None):
        """(K u − Bᵀ C E, mean stress)"""
        ws = self.ws
        if u is not None:
            ws.p[:, 1:-1] = u
            ws.fill_ghosts(ws.p)
        _, stress = ws.apply(u is not None, E)
        return ws.q.copy(), stress / ws.size

    def green(self, r):
        self.ws.r[...] = r
        self.ws.precondition()
        return self.ws.q.copy()


def pcg(problem, E, tol, maxiter, precondition):
    """PCG on K u = −Bᵀ C E; returns iterations, mean stress, the relative Green norm of the final residual and
    the CG coefficients (α, β)."""
    b, mean = problem.apply(None, E)
    r = -b
    g0 = np.sqrt(np.vdot(r, problem.green(r)))
    z = precondition(r)
    rz = rz0 = np.vdot(r, z)
    p = z.copy()
    coefficients = []
    while len(coefficients) < maxiter:
        q, mean_p = problem.apply(p)
        alpha = rz / np.vdot(p, q)
        mean = mean + alpha * mean_p
        r -= alpha * q
        z = precondition(r)
        rz_new = np.vdot(r, z)
        coefficients.append((alpha, rz_new / rz))
        if np.sqrt(max(rz_new, 0.0) / rz0) <= tol:
            break
        p = z + (rz_new / rz) * p
        rz = rz_new
    return len(coefficients), mean, float(np.sqrt(np.vdot(r, problem.green(r))) / g0), coefficients


def ritz_values(coefficients):
    """Eigenvalues of the Lanczos matrix of CG (α_k, β_k)."""
    n = len(coefficients)
    T = np.zeros((n, n))
    for i, (a, _) in enumerate(coefficients):
        T[i, i] = 1 / a + (coefficients[i - 1][1] / coefficients[i - 1][0] if i else 0.0)
        if i + 1 < n:
            T[i, i + 1] = T[i + 1, i] = np.sqrt(coefficients[i][1]) / a
    return np.linalg.eigvalsh(T)


# --------------------------------------------------------------------------------------------------
def element_B(h=(1.0, 1.0, 1.0)):
    """6×24 Mandel strain of one voxel from its 8 corner displacements (corner order np.ndindex(2, 2, 2))."""
    B = np.zeros((6, 24))
    for ci, corner in enumerate(np.ndindex(2, 2, 2)):
        g = np.array([(1 if corner[d] else -1) / (4 * h[d]) for d in range(3)])
        for c in range(3):
            G = np.zeros((3, 3))
            G[c] = g
            B[:, 3 * ci + c] = [G[a, a] if a == d else (G[a, d] + G[d, a]) / np.sqrt(2) for a, d in PAIRS]
    return B


def assemble(phases, stiffness):
    """Sparse K (nodal dofs 3·node + component, node = C index of its voxel's lower corner)."""
    N, n = phases.shape, phases.size
    B = element_B(tuple(1.0 / np.array(N)))  # the unit cube, as the solver's kernels
    index = np.arange(n).reshape(N)
    dofs = np.array([3 * np.roll(index, tuple(-c for c in corner), axis=(0, 1, 2)).ravel() + comp
                     for corner in np.ndindex(2, 2, 2) for comp in range(3)])
    rows, cols, vals = [], [], []
    for p, C in stiffness.items():
        if not np.any(C):
            continue
        ke = B.T @ C @ B
        d = dofs[:, phases.ravel() == p]
        rows.append(np.repeat(d[:, None, :], 24, axis=1).ravel())
        cols.append(np.repeat(d[None, :, :], 24, axis=0).ravel())
        vals.append(np.repeat(ke[:, :, None], d.shape[1], axis=2).ravel())
    return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(3 * n, 3 * n)).tocsr()


def prolongation(N, f, hourglass):
    def one(n):
        i = np.arange(n)
        ic, t = i // f, (i % f) / f
        return sp.coo_matrix((np.concatenate([1 - t, t]), (np.concatenate([i, i]),
                                                           np.concatenate([ic, (ic + 1) % (n // f)]))),
                             shape=(n, n // f)).tocsr()
    P = sp.kron(sp.kron(sp.kron(one(N[0]), one(N[1])), one(N[2])), sp.identity(3)).tocsr()
    if hourglass:
        i, j, k = np.meshgrid(*[np.arange(n) for n in N], indexing="ij")
        signs = [(-1.0) ** (i + j), (-1.0) ** (j + k), (-1.0) ** (i + k), (-1.0) ** (i + j + k)]
        P = sp.hstack([P] + [sp.diags(np.repeat(s.ravel(), 3)) @ P for s in signs]).tocsr()
    return P


def two_grid(problem, K, f, hourglass):
    N = problem.shape
    P = prolongation(N, f, hourglass)
    Kc = (P.T @ K @ P).tocsc()
    Kc = Kc + 1e-9 * abs(Kc.diagonal()).max() * sp.identity(Kc.shape[0])  # the rigid translations
    lu = spl.splu(Kc)
    flat = lambda u: u.transpose(1, 2, 3, 0).ravel()  # noqa: E731
    unflat = lambda v: v.reshape(N + (3,)).transpose(3, 0, 1, 2)  # noqa: E731
    Q = lambda r: unflat(P @ lu.solve(P.T @ flat(r)))  # noqa: E731
    Kx = lambda u: unflat(K @ flat(u))  # noqa: E731

    def precondition(r):
        z = problem.green(r - Kx(Q(r)))
        return z - Q(Kx(z)) + Q(r)
    return precondition


def local_hourglass(problem, K, f):
    """Green + Σ_c P_c (P_cᵀ K P_c)⁺ P_cᵀ over the 12 hourglass-signed functions of each coarse node c."""
    N = problem.shape
    P = prolongation(N, f, True)
    nc = P.shape[1] // 15
    perm = np.array([b * 3 * nc + 3 * c + comp for c in range(nc) for b in (1, 2, 3, 4) for comp in range(3)])
    P = P[:, perm].tocsr()  # the 12 columns of each coarse node contiguous
    A = (P.T @ K @ P).tocoo()
    keep = (A.row // 12) == (A.col // 12)
    D = np.zeros((nc, 12, 12))
    D[A.row[keep] // 12, A.row[keep] % 12, A.col[keep] % 12] = A.data[keep]
    w, V = np.linalg.eigh(D)  # pseudo-inverse: a block whose functions all lie in the void is singular
    big = w > 1e-10 * np.abs(w).max()
    Dinv = np.einsum("nij,nj,nkj->nik", V, np.where(big, 1.0 / np.where(big, w, 1.0), 0.0), V)
    flat = lambda u: u.transpose(1, 2, 3, 0).ravel()  # noqa: E731
    unflat = lambda v: v.reshape(N + (3,)).transpose(3, 0, 1, 2)  # noqa: E731

    def precondition(r):
        y = (P.T @ flat(r)).reshape(nc, 12)
        return problem.green(r) + unflat(P @ np.einsum("nij,nj->ni", Dinv, y).ravel())
    return precondition


def jacobi_scaling(problem, K, stiffness):
    K_I = assemble(problem.phases, {p: np.eye(6) for p in stiffness})
    dK, dI = K.diagonal(), K_I.diagonal()
    S = np.where(dK > 0, np.sqrt(dI / np.where(dK > 0, dK, 1.0)), 0.0)
    return S.reshape(problem.shape + (3,)).transpose(3, 0, 1, 2)


def green_reference(problem, C0):
    """K_0⁻¹ r for K_0 = Bᵀ C_0 B (3×3 blocks per frequency), by numpy FFTs."""
    N = problem.shape
    K = [problem.ws.K0[:, None, None] * problem.ws.C1[None, :, None] * problem.ws.C2[None, None, :],
         problem.ws.C0[:, None, None] * problem.ws.K1[None, :, None] * problem.ws.C2[None, None, :],
         problem.ws.C0[:, None, None] * problem.ws.C1[None, :, None] * problem.ws.K2[None, None, :]]
    Bm = np.zeros((6, 3) + K[0].shape)
    for I, (a, d) in enumerate(PAIRS):
        if a == d:
            Bm[I, a] = K[a]
        else:
            Bm[I, d] += K[a] / np.sqrt(2)
            Bm[I, a] += K[d] / np.sqrt(2)
    A = np.moveaxis(np.einsum("ia...,ij,jb...->ab...", Bm, C0, Bm), (0, 1), (-2, -1))
    zero = (K[0] ** 2 + K[1] ** 2 + K[2] ** 2) <= problem.ws.kmin
    A[zero] = np.eye(3)
    Ainv = np.linalg.inv(A)
    Ainv[zero] = 0.0
    Ainv = np.moveaxis(Ainv, (-2, -1), (0, 1))

    def precondition(r):
        rh = np.fft.rfftn(r, axes=(1, 2, 3))
        return np.fft.irfftn(np.einsum("ab...,b...->a...", Ainv, rh), s=N, axes=(1, 2, 3))
    return precondition


# --------------------------------------------------------------------------------------------------
# Reuse across the 6 load cases (--reuse): the operator is the same for all six right-hand sides
# --------------------------------------------------------------------------------------------------
def _dots(X, Y):
    """Gram matrix ``[⟨X_i, Y_j⟩]`` of two stacks of nodal fields (BLAS on the flattened stacks)."""
    return X.reshape(len(X), -1) @ Y.reshape(len(Y), -1).T


def _combine(W, X):
    """``Σ_i W[i, j] X_i`` for each column ``j`` of ``W``: a new stack."""
    return (W.T @ X.reshape(len(X), -1)).reshape((W.shape[1],) + X.shape[1:])


class Counted:
    """K and K_I⁻¹ of ``Problem`` on single nodal fields, counting the applications."""

    def __init__(self, problem):
        self.problem, self.matvecs, self.greens = problem, 0, 0

    def K(self, u):
        self.matvecs += 1
        return self.problem.apply(u)[0]

    def green(self, r):
        self.greens += 1
        return self.problem.green(r)

    def rhs(self, E):
        return -self.problem.apply(None, E)[0]

    def mean_stress(self, x, E):
        """⟨σ⟩ = ⟨C (E + B x)⟩ of the final iterate (Mandel)."""
        ws = self.problem.ws
        ws.p[:, 1:-1] = x
        ws.fill_ghosts(ws.p)
        return ws.apply(True, E)[1] / ws.size


def k_orthonormalize(P, KP, drop):
    """``P ← P W``, ``KP ← KP W`` with ``(PW)ᵀ K (PW) = I``; directions of ``PᵀKP`` eigenvalue ≤ ``drop`` × the largest
    are dropped (rank-deficient block, converged or dependent columns: the breakdown of O'Leary's block CG)."""
    G = _dots(P, KP)
    lam, W = np.linalg.eigh((G + G.T) / 2)
    keep = lam > drop * lam.max()
    W = W[:, keep] / np.sqrt(lam[keep])
    return _combine(W, P), _combine(W, KP)


def block_pcg(op, rhs, tol, maxiter, drop=1e-12):
    """Block PCG (O'Leary 1980) on all right-hand sides together, Green-preconditioned, with K-orthonormalized
    search directions (rank-revealing: dependent directions are dropped, as in the breakdown-free block CG of Ji &
    Li 2017) and a shrinking block: a column whose Green residual ``‖r‖_{K_I⁻¹}/‖b‖_{K_I⁻¹} ≤ tol`` leaves the
    block. Returns the solutions, the block iterations and the final relative Green residuals."""
    R = np.array(rhs)
    X = np.zeros_like(R)
    Z = np.array([op.green(r) for r in R])
    rz0 = np.einsum("ij,ij->i", R.reshape(len(R), -1), Z.reshape(len(Z), -1))
    P = KP = None
    for it in range(maxiter + 1):
        res = np.sqrt(np.maximum(np.einsum("ij,ij->i", R.reshape(len(R), -1), Z.reshape(len(Z), -1)), 0) / rz0)
        active = np.flatnonzero(res > tol)
        if not len(active) or it == maxiter:
            return X, it, res
        Pn = Z[active] if P is None else Z[active] - _combine(_dots(KP, Z[active]), P)  # K-conjugate to the last P
        P, KP = k_orthonormalize(Pn, np.array([op.K(p) for p in Pn]), drop)
        alpha = _dots(P, R[active])  # (directions, active columns)
        X[active] += _combine(alpha, P)
        R[active] -= _combine(alpha, KP)
        for j in active:
            Z[j] = op.green(R[j])


class Harvest:
    """The smallest eigenpairs of ``K y = θ K_I y`` from the Lanczos vectors of a Green-preconditioned CG solve, in a
    window of ``m`` vectors with the restart of eigCG (Stathopoulos & Orginos 2010): at a full window keep the ``nev``
    smallest Ritz vectors of the window and the ``nev`` of the window without its last vector. The Lanczos vectors
    ``v_j = z_j/√(r_jᵀz_j)`` come with ``K v_j`` (from ``K p_j − β_{j−1} K p_{j−1}``, no extra matvec) and
    ``K_I v_j = r_j/√(r_jᵀz_j)``, and the Rayleigh–Ritz problem of the window is formed explicitly (eigCG updates
    the tridiagonal instead: the same subspace in exact arithmetic). The null space of K (nodes touching only void,
    θ = 0: the right-hand sides are orthogonal to it) is excluded."""

    def __init__(self, m, nev):
        self.m, self.nev = m, nev
        self.V, self.KV, self.MV = [], [], []
        self.last_q, self.beta, self.theta = None, 0.0, np.zeros(0)

    def step(self, z, r, q, rz):
        kz = q if self.last_q is None else q - self.beta * self.last_q
        self.last_q = q
        s = 1.0 / np.sqrt(rz)
        self.V.append(z * s)
        self.KV.append(kz * s)
        self.MV.append(r * s)
        if len(self.V) >= self.m:
            self.restart(eigcg=True)

    def restart(self, eigcg):
        V, KV, MV = (np.array(a) for a in (self.V, self.KV, self.MV))
        A, B = _dots(V, KV), _dots(V, MV)
        A, B = (A + A.T) / 2, (B + B.T) / 2

        def smallest(A, B):
            lb, Vb = np.linalg.eigh(B)
            T = Vb[:, lb > 1e-12 * lb.max()] / np.sqrt(lb[lb > 1e-12 * lb.max()])
            w, Y = np.linalg.eigh(T.T @ A @ T)
            good = w > 1e-9  # θ = 0: the null space of K
            return w[good][:self.nev], (T @ Y)[:, good][:, :self.nev]

        self.theta, U = smallest(A, B)
        if eigcg:
            _, U2 = smallest(A[:-1, :-1], B[:-1, :-1])
            U, _ = np.linalg.qr(np.hstack([U, np.vstack([U2, np.zeros((1, U2.shape[1]))])]))
        self.V, self.KV, self.MV = (list(_combine(U, X)) for X in (V, KV, MV))


def deflated_pcg(op, b, tol, maxiter, space=None, balanced=False, harvest=None):
    """Green-preconditioned CG with the deflation space ``space = (U, KU)`` (``UᵀKU = I``): ``init`` (init-CG,
    Stathopoulos & Orginos 2010: only the initial guess ``x₀ = U Uᵀ b``) or ``balanced`` (every iteration: the
    preconditioner ``(I − U KUᵀ) K_I⁻¹ (I − KU Uᵀ) + U Uᵀ``). Stops on the Green residual ``‖r‖_{K_I⁻¹}/‖b‖_{K_I⁻¹}``
    (the criterion of ``pcg``; the balanced variant pays one more K_I⁻¹ per iteration for it). Returns
    ``(x, iterations, residual)``."""
    x = np.zeros_like(b)
    r = b.copy()
    rz0 = np.vdot(b, op.green(b))
    precondition = op.green
    if space is not None:
        U, KU = space
        c = _dots(U, r[None])[:, 0]
        x += _combine(c[:, None], U)[0]
        r -= _combine(c[:, None], KU)[0]
        if balanced:
            def precondition(r):
                c = _dots(U, r[None])
                y = op.green(r - _combine(c, KU)[0])
                return y + _combine(c - _dots(KU, y[None]), U)[0]
    plain = space is None or not balanced
    z = precondition(r)
    rz = np.vdot(r, z)
    p = z.copy()
    it = 0
    while True:
        green = rz if plain else np.vdot(r, op.green(r))
        if np.sqrt(max(green, 0.0) / rz0) <= tol or it == maxiter:
            return x, it, float(np.sqrt(max(green, 0.0) / rz0))
        q = op.K(p)
        it += 1
        alpha = rz / np.vdot(p, q)
        if harvest is not None:
            harvest.step(z, r, q, rz)
        x += alpha * p
        r -= alpha * q
        z = precondition(r)
        rz_new = np.vdot(r, z)
        beta = rz_new / rz
        if harvest is not None:
            harvest.beta = beta
        p = z + beta * p
        rz = rz_new


def solve_each(rhs, solve):
    """The load cases one after the other: ``solve(case, b) -> (x, iterations, residual)`` for each right-hand side;
    returns the solutions, the iterations per case and the largest final residual."""
    X, iterations, worst = [], [], 0.0
    for case, b in enumerate(rhs):
        x, it, res = solve(case, b)
        X.append(x)
        iterations.append(it)
        worst = max(worst, res)
    return X, iterations, worst


def reuse(args, problem):
    """The rows of ``--reuse``: total K applications for the 6 load cases, one after another (``sequential``: what
    ``pcg`` does), together (``block``), and with the eigenpairs harvested in the earlier solves deflating the
    later ones (``init``, ``balanced``; window ``--window``, ``--nev`` per solve, accumulated)."""
    op = Counted(problem)
    cases = np.eye(6)
    rhs = [op.rhs(E) for E in cases]
    n = rhs[0].size
    rows, reference = [], None

    def record(method, X, iterations, worst, cpu, stored, reference):
        C = np.array([op.mean_stress(x, E) for x, E in zip(X, cases)]).T
        reference = C if reference is None else reference
        rows.append({"N": args.n, "gamma": args.gamma, "method": method, "iterations": "/".join(map(str, iterations)),
                     "matvecs": op.matvecs, "green_applications": op.greens, "green_residual_max": worst,
                     "converged": worst <= args.tol, "dC": float(np.abs(C - reference).max() / np.abs(reference).max()),
                     "cpu_s": cpu, "stored_vectors": stored, "stored_MB": stored * n * 8 / 1e6})
        print(" ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in rows[-1].items()),
              flush=True)
        return reference

    def harvesting(method):
        """``solve`` of :func:`solve_each` that deflates each case by the space harvested from the earlier ones."""
        def solve(case, b):
            nonlocal space
            harvest = Harvest(args.window, args.nev) if method != "sequential" else None
            x, it, res = deflated_pcg(op, b, args.tol, args.maxiter, space, method == "balanced", harvest)
            if harvest is not None:
                if len(harvest.V) > args.nev:
                    harvest.restart(eigcg=False)
                print(f"  {method}, load case {case}: {it} iterations, smallest harvested Ritz values "
                      f"{', '.join(f'{t:.2e}' for t in harvest.theta[:3])}", flush=True)
                U, KU = np.array(harvest.V), np.array(harvest.KV)
                if space is not None:
                    U, KU = np.concatenate([space[0], U]), np.concatenate([space[1], KU])
                space = k_orthonormalize(U, KU, 1e-10)
            return x, it, res
        return solve

    for method in args.reuse:
        op.matvecs = op.greens = 0
        t0 = time.process_time()
        space = None
        if method == "block":
            X, it, res = block_pcg(op, rhs, args.tol, args.maxiter)
            iterations, worst, stored = [it], float(res.max()), 5 * 6  # X, R, Z, P, KP of 6 columns
        else:
            X, iterations, worst = solve_each(rhs, harvesting(method))
            stored = 5 if method == "sequential" else 5 + 3 * args.window + 2 * len(space[0])
        cpu = time.process_time() - t0
        reference = record(method, X, iterations, worst, cpu, stored, reference)
        if method == "balanced":  # a bound: the six cases again, deflated by everything harvested from all six
            op.matvecs = op.greens = 0
            t0 = time.process_time()
            X, iterations, worst = solve_each(
                rhs, lambda case, b, space=space: deflated_pcg(op, b, args.tol, args.maxiter, space, True))
            record("balanced-again", X, iterations, worst, time.process_time() - t0, stored, reference)
    return rows


def main(args):
    from meshes.foam import VoronoiFoam

    args.out.mkdir(parents=True, exist_ok=True)
    phases = VoronoiFoam(args.cells, args.density, args.gamma, seed=args.seed).voxelize(args.n).astype(np.int8)
    solid = isotropic_voigt(1.0, 0.3)
    stiffness = {0: np.zeros((6, 6)), 1: voigt_to_mandel(solid)}
    problem = Problem(phases, stiffness)
    if args.reuse:
        rows = reuse(args, problem)
        with atomic_open(args.out / "bench_fft_preconditioners_reuse.csv") as fh:
            writer = csv.DictWriter(fh, list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"written {args.out / 'bench_fft_preconditioners_reuse.csv'}")
        return
    K = assemble(phases, stiffness)
    builders = {"green": lambda: problem.green,
                "green-jacobi": lambda: (lambda S: lambda r: S * problem.green(S * r))(
                    jacobi_scaling(problem, K, stiffness)),
                "green-hom": lambda: green_reference(problem, voigt_to_mandel(
                    homogenize_fft(phases, [0 * solid, solid], tol=1e-6, threads=1, maxiter=5000).C))}
    for f in args.coarse:
        builders[f"two-grid-{f}"] = lambda f=f: two_grid(problem, K, f, False)
        builders[f"two-grid-hg-{f}"] = lambda f=f: two_grid(problem, K, f, True)
        builders[f"local-hg-{f}"] = lambda f=f: local_hourglass(problem, K, f)
    unknown = sorted(set(args.only or ()) - set(builders))
    if unknown:
        raise SystemExit(f"--only: unknown rows {unknown}; the rows are {sorted(builders)}")
    methods = {name: build() for name, build in builders.items() if not args.only or name in args.only}
    rows = []
    for name, precondition in methods.items():
        for case in args.cases:
            E = np.zeros(6)
            E[case] = 1.0
            t0 = time.process_time()
            it, mean, green_residual, coefficients = pcg(problem, E, args.tol, args.maxiter, precondition)
            rows.append({"N": args.n, "gamma": args.gamma, "preconditioner": name, "case": case, "iterations": it,
                         "converged": it < args.maxiter, "green_residual": green_residual,
                         "C_JJ": mean[case], "cpu_s": time.process_time() - t0})
            print(" ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in rows[-1].items()),
                  flush=True)
            if args.ritz and name == "green":
                smallest = np.array2string(ritz_values(coefficients)[:8], precision=2)
                print(f"  smallest Ritz values of K_I⁻¹K: {smallest}")
    with atomic_open(args.out / "bench_fft_preconditioners.csv") as fh:
        writer = csv.DictWriter(fh, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"written {args.out / 'bench_fft_preconditioners.csv'}")


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("out/bench"))
    p.add_argument("--n", type=int, default=32)
    p.add_argument("--gamma", type=float, default=1.0)
    p.add_argument("--cells", type=int, default=20)
    p.add_argument("--density", type=float, default=0.18)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cases", type=int, nargs="+", default=[0, 3])
    p.add_argument("--coarse", type=int, nargs="*", default=[4, 2], help="coarsening factors of the two-grid rows")
    p.add_argument("--tol", type=float, default=1e-4)
    p.add_argument("--maxiter", type=int, default=2000)
    p.add_argument("--ritz", action="store_true")
    p.add_argument("--only", nargs="+", default=None, help="run only these rows (e.g. green local-hg-2)")
    p.add_argument("--reuse", nargs="+", default=None, choices=("sequential", "block", "init", "balanced"),
                   help="instead of the preconditioner rows: the 6 load cases with these methods (K applications)")
    p.add_argument("--window", type=int, default=40, help="--reuse init/balanced: eigCG window m")
    p.add_argument("--nev", type=int, default=10, help="--reuse init/balanced: eigenpairs kept per solve")
    main(p.parse_args())
