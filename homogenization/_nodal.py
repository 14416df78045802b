"""Displacement form of the rotated scheme (``scheme="pcg"`` of :func:`homogenization.fft.homogenize_fft`).

Willot's rotated discretization is the finite-element method with trilinear hexahedra (the voxels) and one-point
quadrature: the strain field it admits is ``ε = E + B u`` with ``u`` periodic nodal displacements at the voxel
corners and ``B`` the one-point gradient, ``∂N/∂x_d = s_d/(4 h_d)`` (``s_d = ±1`` for a node on the voxel's
upper/lower side along ``d``). In Fourier space ``B`` is ``sym(i k ⊗ ·)`` times a phase common to all components,
with ``k`` exactly the rotated wave vector, so the range of ``B`` is the range of the rotated projection ``G``.

The cell problem is then ``K u = b`` with ``K = Bᵀ C B`` (assembled never: a 27-point stencil applied voxel
plane by voxel plane in ``_kernels.c``) and ``b = −Bᵀ C E``, solved by conjugate gradients preconditioned with
``K_I⁻¹``, ``K_I = Bᵀ B`` the same operator for the Mandel identity as material. ``K_I`` is diagonal in Fourier
space, ``K_I(ξ) = (|k|² I + k kᵀ)/2``, so ``K_I⁻¹ r = (2/|k|²)(r̂ − (k·r̂) k/(2|k|²))`` costs one forward and one
backward FFT of a **3-component** field. Since ``G = B K_I⁻¹ Bᵀ``, the iterates are those of the strain-based
Galerkin CG (``scheme="cg"``) mapped by ``B`` (Ladecký et al., "An optimal preconditioned FFT-accelerated
finite element solver for homogenization", 2023, show this equivalence), and the preconditioned residual norm
``rᵀ K_I⁻¹ r`` is exactly ``‖G[σ]‖²``: same stopping criterion, same iteration counts, same C to rounding — at
half the FFT work (3 instead of 6 components each way) and about half the memory.

Layout: nodal fields are ``(3, n, N2, N3)`` arrays of the rank's planes ``[i0, i0 + n)``; the search direction
``p`` (and the iterate ``x``) carry one ghost plane on each side (``(3, n + 2, N2, N3)``, plane ``l + 1`` = node
plane ``l``), the phase image one leading ghost plane (voxel plane ``i0 − 1``). Serially the ghosts are the
periodic wrap; under MPI they come from the neighbouring ranks (slab decomposition along axis 0, the FFTs by
mpi4py-fft with the spectrum distributed along axis 1).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pyfftw

from foambase.errors import ComputationError
from homogenization import _native

_SQRT2 = np.sqrt(2.0)
MANDEL = np.array([1.0, 1.0, 1.0, _SQRT2, _SQRT2, _SQRT2])  # Voigt (engineering) strain → Mandel: divide
ROUNDOFF = 1e3 * np.finfo(float).eps
_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))  # Voigt order of (c, d)
_VOIGT = ((0, 5, 4), (5, 1, 3), (4, 3, 2))  # tensor component (c, d) → Voigt index


def rotated_tables(n: int, h: float, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis factors of the rotated wave vector.

    For FFT indices ``indices`` of an axis of ``n`` voxels of size ``h``: ``K = (2/h) sin(π m/n)``,
    ``C = cos(π m/n)`` with ``m`` the signed frequency (``C = 0`` exactly at Nyquist), so that
    ``k = (K0 C1 C2, C0 K1 C2, C0 C1 K2)``.
    """
    m = np.where(indices <= n // 2, indices, indices - n).astype(float)
    if n % 2 == 0:
        m[indices == n // 2] = -n / 2
    K = (2.0 / h) * np.sin(np.pi * m / n)
    C = np.cos(np.pi * m / n)
    if n % 2 == 0:
        C[indices == n // 2] = 0.0
    return np.ascontiguousarray(K), np.ascontiguousarray(C)


def stiffness_tables(stiffness_mandel: dict[int, np.ndarray]) -> np.ndarray:
    """The ``tables`` of :class:`NodalWorkspace` from the phases' 6×6 Mandel stiffnesses ``{phase id: C}``.

    ``tables[p]`` maps the Mandel strain to the tensor stress components (the rows of ``C`` divided by
    :data:`MANDEL`); ids without a stiffness (below the largest) get zeros.
    """
    tables = np.zeros((max(stiffness_mandel) + 1, 6, 6))
    for p, C in stiffness_mandel.items():
        tables[p] = C / MANDEL[:, None]
    return tables


class NodalWorkspace:
    """Work arrays, FFTs and kernels of the displacement-form CG on the planes ``[i0, i0 + n)`` of this rank.

    ``phases`` are the rank's voxel planes (int), ``tables[p]`` the 6×6 map from Mandel strain to tensor stress of
    phase ``p`` (:func:`stiffness_tables`). ``comm`` (mpi4py communicator or None) distributes the planes; the
    caller checks the sizes.
    """

    def __init__(self, phases: np.ndarray, tables: np.ndarray, shape: tuple[int, int, int],
                 box: tuple[float, float, float], threads: int, keep: bool, comm=None, i0: int = 0):
        t0 = time.perf_counter()
        self.shape = tuple(int(s) for s in shape)
        N1, N2, N3 = self.shape
        self.comm = comm if comm is not None and comm.Get_size() > 1 else None
        self.n, self.i0 = phases.shape[0], int(i0)
        n, H = self.n, N3 // 2 + 1
        self.size = N1 * N2 * N3
        self.h = np.array([box[d] / self.shape[d] for d in range(3)])
        self.native = _native.load()
        self.tables = np.ascontiguousarray(tables, dtype=float)
        self.weights = MANDEL.copy()
        self.fft_s, self.fft_calls = 0.0, 0
        # phase planes l - 1 ... n - 1 (leading ghost)
        self.phase = np.empty((n + 1, N2, N3), dtype=np.int32)
        self.phase[1:] = phases
        self._exchange(self.phase, lead=1, trail=0)
        # nodal fields
        self.p = pyfftw.empty_aligned((3, n + 2, N2, N3), dtype=np.float64)
        self.x = np.zeros((3, n + 2, N2, N3)) if keep else None
        self.r = pyfftw.empty_aligned((3, n, N2, N3), dtype=np.float64)
        self.q = pyfftw.empty_aligned((3, n, N2, N3), dtype=np.float64)  # K p, and z = K_I⁻¹ r after backward
        if self.comm is None:
            spec = (slice(0, N1), slice(0, N2), slice(0, H))
            self.hat = pyfftw.empty_aligned((3, N1, N2, H), dtype=np.complex128)
            self._forward = pyfftw.FFTW(self.r, self.hat, axes=(1, 2, 3), direction="FFTW_FORWARD",
                                        flags=("FFTW_MEASURE",), threads=threads)
            self._backward = pyfftw.FFTW(self.hat, self.q, axes=(1, 2, 3), direction="FFTW_BACKWARD",
                                         flags=("FFTW_MEASURE", "FFTW_DESTROY_INPUT"), threads=threads)
            self.pfft = None
        else:
            from mpi4py_fft import PFFT

            self.pfft = PFFT(self.comm, self.shape, axes=(0, 1, 2), dtype=np.float64, grid=(-1,),
                             planner_effort="FFTW_MEASURE", threads=threads, collapse=True)
            real, spec = self.pfft.local_slice(False), self.pfft.local_slice(True)
            if (real[0].start, real[0].stop) != (self.i0, self.i0 + n) or real[1:] != (slice(0, N2), slice(0, N3)):
                raise RuntimeError(f"mpi4py-fft distributes the planes as {real}, not [{self.i0}, {self.i0 + n})")
            self.hat = np.empty((3,) + tuple(s.stop - s.start for s in spec), dtype=np.complex128)
        self.plan_s = time.perf_counter() - t0
        # rotated wave-vector tables of this rank's block of the spectrum (mpi4py-fft distributes one axis)
        self.spec = spec
        self.K0, self.C0 = rotated_tables(N1, self.h[0], np.arange(spec[0].start, spec[0].stop))
        self.K1, self.C1 = rotated_tables(N2, self.h[1], np.arange(spec[1].start, spec[1].stop))
        self.K2, self.C2 = rotated_tables(N3, self.h[2], np.arange(spec[2].start, spec[2].stop))
        self.kmin = 1e-20 * float(np.sum((2.0 / self.h) ** 2))  # |k|² below this: k = 0 (mean, hourglass)
        # threads: one contiguous range of planes each (real space), and of axis-0 planes of the spectrum
        self.ranges = [(int(r[0]), int(r[-1]) + 1) for r in np.array_split(np.arange(n), threads) if len(r)]
        self.spec_ranges = [(int(r[0]), int(r[-1]) + 1) for r in np.array_split(np.arange(self.hat.shape[1]), threads)
                            if len(r)]
        self.pool = ThreadPoolExecutor(len(self.ranges)) if len(self.ranges) > 1 else None

    # ---------------------------------------------------------------------------------------------------
    @property
    def nbytes(self) -> int:
        """Bytes of this rank's work arrays (fields, spectrum, phase planes, tables)."""
        arrays = [self.p, self.r, self.q, self.hat, self.phase, self.tables]
        arrays += [self.x] if self.x is not None else []
        return int(sum(a.nbytes for a in arrays))

    def close(self):
        if self.pool is not None:
            self.pool.shutdown()
        if self.pfft is not None:
            self.pfft.destroy()

    def _run(self, kernel: Callable, ranges) -> np.ndarray:
        """``kernel(a, b) -> array`` on each range (one thread each), summed."""
        if self.pool is None or len(ranges) == 1:
            return sum(np.atleast_1d(kernel(a, b)) for a, b in ranges)
        return sum(self.pool.map(lambda ab: np.atleast_1d(kernel(*ab)), ranges))

    def allsum(self, values) -> np.ndarray:
        """Sum over ranks (a copy; identity serially)."""
        values = np.array(values, dtype=float, ndmin=1)
        if self.comm is not None:
            out = np.empty_like(values)
            from mpi4py import MPI

            self.comm.Allreduce(values, out, op=MPI.SUM)
            return out
        return values

    def _exchange(self, array: np.ndarray, lead: int, trail: int) -> None:
        """Fill the ghost planes of ``array`` (planes along its axis -3): ``lead`` planes before, ``trail`` after."""
        n = array.shape[-3] - lead - trail
        first, last = (slice(lead, lead + 1), slice(lead + n - 1, lead + n))
        if self.comm is None:
            if lead:
                array[..., 0:1, :, :] = array[..., last, :, :]
            if trail:
                array[..., lead + n:lead + n + 1, :, :] = array[..., first, :, :]
            return
        size, rank = self.comm.Get_size(), self.comm.Get_rank()
        nxt, prv = (rank + 1) % size, (rank - 1) % size
        if lead:  # my last plane goes to the next rank's leading ghost
            send = np.ascontiguousarray(array[..., last, :, :])
            recv = np.empty_like(send)
            self.comm.Sendrecv(send, dest=nxt, sendtag=11, recvbuf=recv, source=prv, recvtag=11)
            array[..., 0:1, :, :] = recv
        if trail:  # my first plane goes to the previous rank's trailing ghost
            send = np.ascontiguousarray(array[..., first, :, :])
            recv = np.empty_like(send)
            self.comm.Sendrecv(send, dest=prv, sendtag=12, recvbuf=recv, source=nxt, recvtag=12)
            array[..., lead + n:lead + n + 1, :, :] = recv

    # ---------------------------------------------------------------------------------------------------
    def apply(self, with_p: bool, E: np.ndarray | None) -> tuple[float, np.ndarray]:
        """``q ← Bᵀ σ(E + B p)`` (``p`` = 0 if not ``with_p``).

        Returns ``(Σ e·σ, Σ σ)`` over this rank's voxels (Mandel energy, tensor stress components; not yet summed
        over ranks).
        """
        N2, N3 = self.shape[1], self.shape[2]
        Ec = None if E is None else np.ascontiguousarray(E, dtype=float)
        if self.native is not None:
            ffi, lib = self.native
            ptr = lambda a, t="double *": ffi.cast(t, a.ctypes.data)  # noqa: E731
            pp = ptr(self.p) if with_p else ffi.NULL
            Ep = ptr(Ec) if Ec is not None else ffi.NULL

            def kernel(a, b):
                sums = np.zeros(7)
                lib.ff_hex_apply(N2, N3, a, b, pp, self.p[0].size, ptr(self.phase, "int32_t *"), len(self.tables),
                                 ptr(self.tables), ptr(self.weights), Ep, ptr(self.h), ptr(self.q), self.q[0].size,
                                 ptr(sums))
                return sums
        else:
            def kernel(a, b):
                return _apply_numpy(self, a, b, with_p, Ec)
        sums = self._run(kernel, self.ranges)
        return float(sums[0]), sums[1:]

    def precondition(self) -> float:
        """``q ← K_I⁻¹ r`` by FFT; returns ``rᵀ K_I⁻¹ r`` (this rank's share of the spectrum)."""
        self._transform(forward=True)
        _, N2loc, Hloc = self.hat.shape[1:]
        H = self.shape[2] // 2 + 1
        nyquist = self.shape[2] % 2 == 0 and H > 1
        kernel = self._green_kernel(N2loc, Hloc, H, self.spec[2].start, nyquist, 1.0 / self.size)
        rz = float(self._run(kernel, self.spec_ranges)[0])
        self._transform(forward=False)
        return rz

    def _transform(self, forward: bool) -> None:
        """``hat ← FFT(r)`` or ``q ← FFT⁻¹(hat)`` (unnormalised), timed in ``fft_s``."""
        t0 = time.perf_counter()
        if self.pfft is None:
            (self._forward if forward else self._backward).execute()
        elif forward:
            for c in range(3):
                self.pfft.forward(self.r[c], self.hat[c], normalize=False)
        else:
            for c in range(3):
                self.pfft.backward(self.hat[c], self.q[c])
        self.fft_s += time.perf_counter() - t0
        self.fft_calls += 1

    def _green_kernel(self, N2loc: int, Hloc: int, H: int, k_lo: int, nyquist: bool, scale: float):
        """``kernel(a, b)``: ``hat ← K_I⁻¹ hat`` on the spectrum planes ``a … b − 1``; returns ``[rᵀ K_I⁻¹ r]``."""
        if self.native is not None:
            ffi, lib = self.native
            ptr = lambda a: ffi.cast("double *", a.ctypes.data)  # noqa: E731
            stride = 2 * self.hat[0].size

            def kernel(a, b):
                return lib.ff_hex_green(b - a, N2loc, Hloc,
                                        ffi.cast("double *", self.hat.ctypes.data) + 2 * a * N2loc * Hloc, stride,
                                        ptr(self.K0) + a, ptr(self.C0) + a, ptr(self.K1), ptr(self.C1),
                                        ptr(self.K2), ptr(self.C2), self.kmin, scale, nyquist, k_lo, H)
        else:
            def kernel(a, b):
                return _green_numpy(self, a, b, scale, nyquist, k_lo, H)
        return kernel

    def axpby(self, alpha: float, x: np.ndarray, beta: float, y: np.ndarray, x_ghost: int = 0,
              y_ghost: int = 0) -> None:
        """``y ← α x + β y`` on this rank's planes; ``*_ghost`` = 1 for the arrays with ghost planes."""
        plane = self.shape[1] * self.shape[2]
        if self.native is not None:
            ffi, lib = self.native
            coefficients = np.full(3, alpha)
            cp = ffi.cast("double *", coefficients.ctypes.data)
            xp, yp = ffi.cast("double *", x.ctypes.data), ffi.cast("double *", y.ctypes.data)

            def kernel(a, b):
                lib.ff_axpby((b - a) * plane, 3, cp, xp + (a + x_ghost) * plane, x[0].size, beta,
                             yp + (a + y_ghost) * plane, y[0].size, 0)
                return 0.0
        else:
            def kernel(a, b):
                ys = y[:, a + y_ghost:b + y_ghost]
                if beta == 0.0:  # y may hold garbage (NaN): never read it
                    np.multiply(x[:, a + x_ghost:b + x_ghost], alpha, out=ys)
                else:
                    ys *= beta
                    ys += alpha * x[:, a + x_ghost:b + x_ghost]
                return 0.0
        self._run(kernel, self.ranges)

    def fill_ghosts(self, array: np.ndarray) -> None:
        """Ghost planes of a nodal field with one ghost plane on each side (``p``, ``x``)."""
        self._exchange(array, lead=1, trail=1)

    def strain_stress(self, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Voxel strain ``E + B x`` (Voigt, engineering shear) and stress (Voigt) of this rank's planes."""
        self.fill_ghosts(self.x)
        e, tau = _voxel_fields(self, self.x, 0, self.n, E)
        return e[:, 1:] * MANDEL[:, None, None, None], tau[:, 1:]


# --------------------------------------------------------------------------------------------------------------
# numpy kernels (no C compiler): the same algebra as ff_hex_apply / ff_hex_green, block by block
# --------------------------------------------------------------------------------------------------------------
def _voxel_fields(ws: NodalWorkspace, p: np.ndarray | None, a: int, b: int, E):
    """Mandel strain and tensor stress of voxel planes ``a − 1 … b − 1`` (local) from the padded nodal field."""
    N2, N3 = ws.shape[1], ws.shape[2]
    if p is None:
        e = np.zeros((6, b - a + 1, N2, N3))
    else:
        P = p[:, a:b + 2]  # node planes a − 1 … b
        s, d = 0.5 * (P[:, :-1] + P[:, 1:]), (P[:, 1:] - P[:, :-1]) / ws.h[0]
        roll = np.roll
        g = np.empty((3, 3) + s.shape[1:])
        g[:, 0] = 0.25 * (d + roll(d, -1, 3) + roll(d, -1, 2) + roll(roll(d, -1, 2), -1, 3))
        a3 = 0.5 * (s + roll(s, -1, 3))
        g[:, 1] = (roll(a3, -1, 2) - a3) / ws.h[1]
        a2 = 0.5 * (s + roll(s, -1, 2))
        g[:, 2] = (roll(a2, -1, 3) - a2) / ws.h[2]
        e = np.empty((6,) + s.shape[1:])
        for I, (c, dd) in enumerate(_PAIRS):
            e[I] = g[c, c] if c == dd else (g[c, dd] + g[dd, c]) / _SQRT2
    if E is not None:
        e += np.asarray(E)[:, None, None, None]
    ids = ws.phase[a:b + 1]
    tau = np.zeros_like(e)
    for ph in np.unique(ids):
        T = ws.tables[ph]
        if np.any(T):
            tau += np.einsum("ij,j...->i...", T, e) * (ids == ph)
    return e, tau


def _apply_numpy(ws: NodalWorkspace, a: int, b: int, with_p: bool, E) -> np.ndarray:
    e, tau = _voxel_fields(ws, ws.p if with_p else None, a, b, E)
    sums = np.zeros(7)
    sums[0] = float(np.sum(ws.weights[:, None, None, None] * e[:, 1:] * tau[:, 1:]))
    sums[1:] = tau[:, 1:].sum(axis=(1, 2, 3))
    A, B = tau[:, :-1], tau[:, 1:]  # voxel planes l − 1 and l of node planes a … b − 1
    roll = np.roll
    f = 0.25 / ws.h
    for c in range(3):
        V = A[_VOIGT[c][0]] - B[_VOIGT[c][0]]
        t0 = V + roll(V, 1, 1) + roll(V, 1, 2) + roll(roll(V, 1, 1), 1, 2)
        U = A[_VOIGT[c][1]] + B[_VOIGT[c][1]]
        W = U + roll(U, 1, 2)
        t1 = roll(W, 1, 1) - W
        U = A[_VOIGT[c][2]] + B[_VOIGT[c][2]]
        W = U + roll(U, 1, 1)
        t2 = roll(W, 1, 2) - W
        ws.q[c, a:b] = f[0] * t0 + f[1] * t1 + f[2] * t2
    return sums


def _green_numpy(ws: NodalWorkspace, a: int, b: int, scale: float, nyquist: bool, k_lo: int, H: int) -> float:
    k = [ws.K0[a:b, None, None] * ws.C1[None, :, None] * ws.C2[None, None, :],
         ws.C0[a:b, None, None] * ws.K1[None, :, None] * ws.C2[None, None, :],
         ws.C0[a:b, None, None] * ws.C1[None, :, None] * ws.K2[None, None, :]]
    kk = k[0] ** 2 + k[1] ** 2 + k[2] ** 2
    zero = kk <= ws.kmin
    kk = np.where(zero, 1.0, kk)
    amp = np.where(zero, 0.0, 2.0 * scale / kk)
    r = ws.hat[:, a:b]
    kr = (k[0] * r[0] + k[1] * r[1] + k[2] * r[2]) * (0.5 / kk)
    z = np.stack([amp * (r[c] - kr * k[c]) for c in range(3)])
    index = k_lo + np.arange(kk.shape[-1])  # global indices of the last axis
    w = np.where((index == 0) | (nyquist & (index == H - 1)), 1.0, 2.0)
    total = float(np.sum(w * np.real(np.conj(r) * z).sum(axis=0)))
    r[...] = z
    return total


# --------------------------------------------------------------------------------------------------------------
# The solver
# --------------------------------------------------------------------------------------------------------------
def load_norm(ws: NodalWorkspace, stiffness_mandel: dict, counts: dict, E: np.ndarray) -> float:
    """``‖C : E‖`` (L² sum over voxels, Mandel) from the phase counts."""
    return float(np.sqrt(sum(counts[p] * float(np.sum((stiffness_mandel[p] @ E) ** 2)) for p in counts)))


def solve_pcg(ws: NodalWorkspace, E: np.ndarray, tol: float, maxiter: int, report: Callable, load: float):
    """One load case (Mandel macroscopic strain ``E``): returns ``(⟨σ⟩ Voigt, history, converged, message)``.

    ``report(iteration, residual, ⟨σ⟩)`` after every iteration and at iteration 0; the residual is
    ``sqrt(rᵀ K_I⁻¹ r / r₀ᵀ K_I⁻¹ r₀) = ‖G[σ]‖ / ‖G[C:E]‖``.
    """
    _, stress = ws.apply(False, E)  # q = Bᵀ C E
    mean = ws.allsum(stress) / ws.size
    ws.axpby(-1.0, ws.q, 0.0, ws.r)  # r₀ = b = −Bᵀ C E
    if ws.x is not None:
        ws.x[...] = 0.0
    rz = float(ws.allsum(ws.precondition())[0])  # q = z₀
    r0 = np.sqrt(max(rz, 0.0))
    if r0 <= ROUNDOFF * load:
        report(0, 0.0, mean)
        return mean, [0.0], True, ""
    history = [1.0]
    report(0, 1.0, mean)
    ws.axpby(1.0, ws.q, 0.0, ws.p, y_ghost=1)  # p = z₀
    for it in range(1, maxiter + 1):
        ws.fill_ghosts(ws.p)
        pKp, stress_p = ws.apply(True, None)  # q = K p
        totals = ws.allsum(np.concatenate([[pKp], stress_p]))
        pKp = float(totals[0])
        if not np.isfinite(pKp):
            raise ComputationError(f"PCG: <p, K p> = {pKp} at iteration {it}: the fields overflowed or hold NaN")
        if pKp <= 0.0:
            return mean, history, False, f"CG breakdown at iteration {it}: <p, K p> = {pKp:.3g}"
        alpha = rz / pKp
        mean = mean + alpha * totals[1:] / ws.size
        if ws.x is not None:
            ws.axpby(alpha, ws.p, 1.0, ws.x, x_ghost=1, y_ghost=1)
        ws.axpby(-alpha, ws.q, 1.0, ws.r)  # r ← r − α K p
        rz_new = float(ws.allsum(ws.precondition())[0])  # q = z = K_I⁻¹ r
        history.append(float(np.sqrt(max(rz_new, 0.0)) / r0))
        report(it, history[-1], mean)
        if history[-1] <= tol:
            return mean, history, True, ""
        ws.axpby(1.0, ws.q, rz_new / rz, ws.p, y_ghost=1)  # p ← z + β p
        rz = rz_new
    return mean, history, False, f"CG did not reach tol in maxiter = {maxiter} iterations"


# --------------------------------------------------------------------------------------------------------------
# Fully integrated trilinear voxels (discretization="hex8")
# --------------------------------------------------------------------------------------------------------------
GAUSS = (0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0))  #: 2-point Gauss abscissae on [0, 1]


def hex8_gradients(h: np.ndarray, points=None) -> np.ndarray:
    """Mandel strain matrices ``B_g`` (6×24) of a trilinear voxel of sizes ``h`` at the points ``g``.

    Default points: the 2×2×2 Gauss points; local coordinates in ``[0, 1]³``; node ``n = 4 da + 2 db + dc`` at
    ``(da, db, dc)``, dof ``3 n + c``. ``points=[(0.5, 0.5, 0.5)]`` gives the one-point (rotated) gradient.
    """
    if points is None:
        points = [(a, b, c) for a in GAUSS for b in GAUSS for c in GAUSS]
    out = []
    for t in points:
        B = np.zeros((6, 24))
        for n in range(8):
            corner = ((n >> 2) & 1, (n >> 1) & 1, n & 1)
            w = [t[d] if corner[d] else 1.0 - t[d] for d in range(3)]
            dN = [(1.0 if corner[d] else -1.0) / h[d] * np.prod([w[e] for e in range(3) if e != d])
                  for d in range(3)]
            for I, (c, d) in enumerate(_PAIRS):
                if c == d:
                    B[I, 3 * n + c] += dN[c]
                else:  # Mandel shear: (∂_d u_c + ∂_c u_d)/√2
                    B[I, 3 * n + c] += dN[d] / _SQRT2
                    B[I, 3 * n + d] += dN[c] / _SQRT2
        out.append(B)
    return np.array(out)


def hex8_element_matrices(tables: np.ndarray, h: np.ndarray, points=None) -> np.ndarray:
    """Element stiffnesses ``Ke[p] = mean_g B_gᵀ C_p B_g`` (24×24) of every phase.

    Normalised like the rotated stencil (``K = Σ_voxels Ke``: no voxel-volume factor); ``C_p`` the Mandel
    stiffness behind ``tables[p]``.
    """
    B = hex8_gradients(h, points)
    Ke = np.empty((len(tables), 24, 24))
    for p, T in enumerate(tables):
        C = T * MANDEL[:, None]  # tables hold Mandel strain → tensor stress; back to Mandel stress
        Ke[p] = np.mean([Bg.T @ C @ Bg for Bg in B], axis=0)
        Ke[p] = 0.5 * (Ke[p] + Ke[p].T)
    return Ke


def hex8_weight_table(n: int, h: float, indices: np.ndarray) -> np.ndarray:
    """``W = cos²(π m/n) + sin²(π m/n)/3`` per FFT index: the Gauss-point mean of ``|C + i σ S/√3|²``."""
    K, C = rotated_tables(n, h, indices)
    S = K * h / 2.0
    return np.ascontiguousarray(C * C + S * S / 3.0)


class Hex8Workspace(NodalWorkspace):
    """:class:`NodalWorkspace` of the fully integrated trilinear voxels (``discretization="hex8"``).

    ``K = Σ_voxels Ke(phase)`` with the 2×2×2-Gauss element matrices (:func:`hex8_element_matrices`), applied
    voxel plane by voxel plane (``ff_hex8_apply``); the preconditioner is ``K_I⁻¹``, ``K_I`` the same
    discretization with the Mandel identity as material, a real symmetric 3×3 matrix per wave vector
    (``M = (tr A I + A)/2``, ``A_cd = K_c C_c K_d C_d W_f``, ``A_cc = K_c² W_d W_f``: the rotated scheme's
    ``C_l²`` replaced by the Gauss mean ``W_l = C_l² + S_l²/3 ≥ 1/3``), positive definite at every ``ξ ≠ 0``: no
    hourglass modes. The load ``Bᵀ C E`` and the mean stress ``⟨C (E + B u)⟩`` involve only the Gauss-point mean
    of the strain, which is the voxel-centre (one-point) strain: they are the rotated kernel's.
    """

    def __init__(self, phases, tables, shape, box, threads, keep, comm=None, i0=0):
        super().__init__(phases, tables, shape, box, threads, keep, comm=comm, i0=i0)
        self.Ke = np.ascontiguousarray(hex8_element_matrices(self.tables, self.h))
        self.active = np.array([np.any(T) for T in self.tables], dtype=np.int32)
        N1, N2, N3 = self.shape
        self.W0 = hex8_weight_table(N1, self.h[0], np.arange(self.spec[0].start, self.spec[0].stop))
        self.W1 = hex8_weight_table(N2, self.h[1], np.arange(self.spec[1].start, self.spec[1].stop))
        self.W2 = hex8_weight_table(N3, self.h[2], np.arange(self.spec[2].start, self.spec[2].stop))

    @property
    def nbytes(self) -> int:
        return super().nbytes + int(self.Ke.nbytes)

    def apply(self, with_p: bool, E: np.ndarray | None) -> tuple[float, np.ndarray]:
        """``q ← K p`` (``with_p``, ``E`` None) or ``q ← Bᵀ C E`` (load; the rotated kernel, see the class)."""
        if not with_p or E is not None:
            if with_p:
                raise ValueError("Hex8Workspace.apply: K p and the load are separate calls")
            return super().apply(False, E)
        N2, N3 = self.shape[1], self.shape[2]
        if self.native is not None:
            ffi, lib = self.native
            ptr = lambda a, t="double *": ffi.cast(t, a.ctypes.data)  # noqa: E731

            def kernel(a, b):
                sums = np.zeros(7)
                lib.ff_hex8_apply(N2, N3, a, b, ptr(self.p), self.p[0].size, ptr(self.phase, "int32_t *"),
                                  ptr(self.Ke), ptr(self.active, "int32_t *"), ptr(self.tables), ptr(self.h),
                                  ptr(self.q), self.q[0].size, ptr(sums))
                return sums
        else:
            def kernel(a, b):
                return _hex8_apply_numpy(self, a, b)
        sums = self._run(kernel, self.ranges)
        return float(sums[0]), sums[1:]

    def _green_kernel(self, N2loc: int, Hloc: int, H: int, k_lo: int, nyquist: bool, scale: float):
        """As :meth:`NodalWorkspace._green_kernel` with the hex8 reference stiffness ``K_I``."""
        if self.native is not None:
            ffi, lib = self.native
            ptr = lambda a: ffi.cast("double *", a.ctypes.data)  # noqa: E731
            stride = 2 * self.hat[0].size

            def kernel(a, b):
                return lib.ff_hex8_green(b - a, N2loc, Hloc,
                                         ffi.cast("double *", self.hat.ctypes.data) + 2 * a * N2loc * Hloc, stride,
                                         ptr(self.K0) + a, ptr(self.C0) + a, ptr(self.W0) + a, ptr(self.K1),
                                         ptr(self.C1), ptr(self.W1), ptr(self.K2), ptr(self.C2), ptr(self.W2),
                                         self.kmin, scale, nyquist, k_lo, H)
        else:
            def kernel(a, b):
                return _hex8_green_numpy(self, a, b, scale, nyquist, k_lo, H)
        return kernel


def _hex8_apply_numpy(ws: Hex8Workspace, a: int, b: int) -> np.ndarray:
    """``ff_hex8_apply`` in numpy: gather the 8 nodes of voxel planes ``a − 1 … b − 1``, ``Ke u``, scatter."""
    m = b - a + 1
    P = ws.p[:, a:b + 2]  # node planes a − 1 … b
    U = np.empty((24, m) + P.shape[2:])
    for n in range(8):
        da, db, dc = (n >> 2) & 1, (n >> 1) & 1, n & 1
        U[3 * n:3 * n + 3] = np.roll(P[:, da:da + m], (-db, -dc), axis=(2, 3))
    ids = ws.phase[a:b + 1]
    F = np.zeros_like(U)
    for ph in np.unique(ids):
        if ws.active[ph]:
            F += np.einsum("rc,c...->r...", ws.Ke[ph], U) * (ids == ph)
    sums = np.zeros(7)
    sums[0] = float(np.sum(U[:, 1:] * F[:, 1:]))
    _, tau = _voxel_fields(ws, ws.p, a, b, None)
    sums[1:] = tau[:, 1:].sum(axis=(1, 2, 3))
    out = np.zeros((3, b - a) + P.shape[2:])
    for n in range(8):
        da, db, dc = (n >> 2) & 1, (n >> 1) & 1, n & 1
        part = F[3 * n:3 * n + 3, :-1] if da else F[3 * n:3 * n + 3, 1:]  # voxel plane l − 1 (upper) or l (lower)
        out += np.roll(part, (db, dc), axis=(2, 3))
    ws.q[:, a:b] = out
    return sums


def _hex8_green_numpy(ws: Hex8Workspace, a: int, b: int, scale: float, nyquist: bool, k_lo: int, H: int) -> float:
    K = [ws.K0[a:b, None, None], ws.K1[None, :, None], ws.K2[None, None, :]]
    C = [ws.C0[a:b, None, None], ws.C1[None, :, None], ws.C2[None, None, :]]
    W = [ws.W0[a:b, None, None], ws.W1[None, :, None], ws.W2[None, None, :]]
    shape = np.broadcast_shapes(*(k.shape for k in K))
    A = {}
    for c in range(3):
        d, f = [e for e in range(3) if e != c]
        A[c, c] = np.broadcast_to(K[c] ** 2 * W[d] * W[f], shape)
    for c, d in ((0, 1), (0, 2), (1, 2)):
        A[c, d] = np.broadcast_to(K[c] * C[c] * K[d] * C[d] * W[3 - c - d], shape)
    tr = A[0, 0] + A[1, 1] + A[2, 2]
    zero = tr <= ws.kmin
    M = {key: 0.5 * value + (0.5 * tr if key[0] == key[1] else 0.0) for key, value in A.items()}
    M[0, 0], M[1, 1], M[2, 2] = (np.where(zero, 1.0, M[c, c]) for c in range(3))
    adj = {(0, 0): M[1, 1] * M[2, 2] - M[1, 2] ** 2, (0, 1): M[0, 2] * M[1, 2] - M[0, 1] * M[2, 2],
           (0, 2): M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1], (1, 1): M[0, 0] * M[2, 2] - M[0, 2] ** 2,
           (1, 2): M[0, 1] * M[0, 2] - M[0, 0] * M[1, 2], (2, 2): M[0, 0] * M[1, 1] - M[0, 1] ** 2}
    s = np.where(zero, 0.0, scale / (M[0, 0] * adj[0, 0] + M[0, 1] * adj[0, 1] + M[0, 2] * adj[0, 2]))
    inv = lambda c, d: s * adj[min(c, d), max(c, d)]  # noqa: E731
    r = ws.hat[:, a:b]
    z = np.stack([inv(c, 0) * r[0] + inv(c, 1) * r[1] + inv(c, 2) * r[2] for c in range(3)])
    index = k_lo + np.arange(shape[-1])
    w = np.where((index == 0) | (nyquist & (index == H - 1)), 1.0, 2.0)
    total = float(np.sum(w * np.real(np.conj(r) * z).sum(axis=0)))
    r[...] = z
    return total
