"""FFT homogenization of a periodic voxel image: conjugate gradients (strain or displacement), Moulinec–Suquet.

The cell problem
----------------
For a macroscopic strain ``E`` find the periodic strain ``ε = E + ε̃`` of the box ``(L1, L2, L3)`` (default the
unit cube; voxel sizes ``h_j = L_j/N_j``), ``ε̃`` compatible with zero mean, such that ``div σ = 0`` with
``σ = C(x) : ε``. The homogenized stiffness is read from the volume averages: ``C_hom E = ⟨σ⟩``; six unit strains
give its six columns.

Internally strains and stiffnesses are in **Mandel** form (Voigt order, shear components times ``√2``; see
:mod:`homogenization.tensors`), so that the Euclidean inner product of 6-vectors is the tensor one, and norms
are Mandel norms; the stress fed to the FFT is kept as tensor components (see :class:`_Workspace`).
At the boundary (``materials``, ``macro_strains``, ``C``, ``fields``) everything is Voigt with engineering shear.

The projection ``G``
--------------------
With ``n(ξ) = k(ξ)/|k(ξ)|`` the unit discrete wave vector, the orthogonal (``L²``) projection onto compatible,
zero-mean strain fields acts frequency-wise on a symmetric ``τ̂``::

    G[τ̂] = n ⊗ w + w ⊗ n,   w = τ̂ n − ½ (n · τ̂ n) n,     G = 0 where k = 0 (ξ = 0 and the modes below)

and the Moulinec–Suquet Green operator of an isotropic reference medium ``(λ0, μ0)`` is
``Γ0[τ̂] = (n ⊗ w + w ⊗ n)/(2 μ0)`` with ``w = τ̂ n − (λ0 + μ0)/(λ0 + 2 μ0) (n · τ̂ n) n``.
The wave vector ``k`` depends on the discretization:

``"spectral"``
    ``k = ξ`` (continuous frequencies, Moulinec & Suquet 1998). On an even grid the Nyquist frequencies
    (some ``m_j = −N_j/2``) carry no fluctuation (``G = 0`` there), as in Moulinec & Suquet. Exact when the
    microstructure has no Nyquist content (odd grids; a laminate with an even number of voxel layers); a laminate
    with an odd number of layers is off by 3e-3 at N = 16 and 7e-4 at N = 32 (∝ N⁻²).
``"rotated"``
    Willot (2015): ``k_j ∝ (2/h_j) sin(ξ_j h_j/2) ∏_{l≠j} cos(ξ_l h_l/2)``, equivalent to trilinear hexahedra
    with one-point integration; no Gibbs ringing, well posed with void. Where this ``k`` vanishes away from
    ``ξ = 0`` (two components at Nyquist on an even grid: the hourglass modes) ``G = 0``.
``"hex8"``
    Trilinear hexahedra (the voxels) with full 2×2×2 Gauss integration, the conforming finite-element model of the
    voxel image (Ladecký et al. 2023; FANS's HEX8 element): no hourglass modes, stiffer than ``"rotated"``, so the
    two bracket the voxel geometry's moduli. Solved for the nodal displacements only (``scheme="pcg"``, its
    Green preconditioner the inverse of the same discretization's stiffness for the identity material, a 3×3
    matrix per wave vector; :class:`homogenization._nodal.Hex8Workspace`).

Schemes and stopping criterion
------------------------------
``"pcg"`` (default with ``"rotated"`` and ``"hex8"``; Ladecký et al. 2023)
    The rotated scheme solved for the nodal displacements ``u`` of the trilinear voxels: ``Bᵀ C B u = −Bᵀ C E``
    by conjugate gradients preconditioned with the Green operator ``(Bᵀ B)⁻¹`` (diagonal in Fourier space), see
    :mod:`homogenization._nodal`. Its iterates are those of ``"cg"`` mapped by ``B``: same residuals, iteration
    counts and C, with one FFT pair of 3 (not 6) components per iteration and about half the work arrays.
    It also runs distributed over MPI ranks (``comm=``). With ``"hex8"`` the same CG solves the fully integrated
    stiffness ``K = Σ_g B_gᵀ C B_g / 8`` preconditioned by ``K_I⁻¹`` of that discretization; it stops on the
    relative preconditioned residual ``sqrt(rᵀ K_I⁻¹ r / r₀ᵀ K_I⁻¹ r₀)``, the counterpart of ``‖G[σ]‖/‖G[C:E]‖``.
``"cg"`` (default with ``"spectral"``; Zeman et al. 2010, Vondřejc et al. 2014)
    Solve ``G[C : ε̃] = −G[C : E]`` for ``ε̃`` in the range of ``G`` with conjugate gradients; the operator is
    symmetric positive semi-definite there (Mandel inner product), also with a zero-stiffness phase.
``"basic"`` (Moulinec & Suquet 1998)
    ``ε ← ε − Γ0[C : ε]`` with the reference medium of :func:`reference_medium`; it needs every phase present
    to be positive definite.

All stop when the **equilibrium residual relative to the load**, ``‖G[σ]‖ / ‖G[C : E]‖`` (``L²`` norms of
Mandel fields), is ``≤ tol``. For CG it is exactly the relative CG residual ``‖r_k‖/‖r_0‖``; for ``"pcg"`` the
relative preconditioned residual ``sqrt(rᵀ K_I⁻¹ r / r₀ᵀ K_I⁻¹ r₀)``, the same number. If ``G[C : E]``
vanishes to round-off (``‖G[C:E]‖ ≤ 1e3 ε_mach ‖C:E‖``, e.g. a homogeneous image) the case is solved by
``ε = E`` in zero iterations. Not reaching ``tol`` within ``maxiter`` raises :class:`FFTConvergenceError`
(or, with ``raise_on_failure=False``, returns a result with ``converged=False``).

Units: the solver works on the stiffnesses scaled by one power of two (largest entry in [1, 2)) and on each load
case's strain scaled likewise, and scales ``⟨σ⟩`` and the fields back exactly; its squared norms therefore never
overflow or underflow, and ``C`` of moduli in any unit (1e200, 1e-170) is that unit times ``C`` of the moduli in
another (bit for bit when the ratio is a power of two). A zero load case, an image whose phases all have zero
stiffness and non-finite materials are :class:`~foambase.errors.InputError`; a residual, ``⟨σ⟩`` or ``C`` that is
not finite is a :class:`~foambase.errors.ComputationError`, never returned.

With a zero-stiffness void CG needs hundreds of iterations on thin-strut foams. The slow modes are
near-zero-energy hourglass patterns of the one-point-integrated voxels along the pore surfaces (smallest Ritz
values of the Green-preconditioned operator ~1e-5 at N = 32 and 64): no Fourier-diagonal operator sees where the
surfaces are, and neither a Jacobi scaling (the Green–Jacobi preconditioner) nor a coarse-grid correction removes
them (measurements in ``docs/benchmarks``).

Performance
-----------
``"cg"`` and ``"basic"``: one pair of pyfftw plans (``FFTW_MEASURE``, multithreaded, batched over the six
components) per call; FFTW keeps its wisdom for the process, so planning a shape again is immediate. All ``N³``
work arrays are allocated once for all load cases. Between the transforms, each iteration makes three passes over
memory: the constitutive update (with the CG direction update and ``⟨p, C:p⟩`` fused in), the Fourier kernel ``G``
and the residual update with its norm. They are fused C kernels (``_kernels.c``, compiled once per machine by
:mod:`homogenization._native`, called through cffi on blocks of planes on ``threads`` threads); without a C
compiler the same algebra runs as numpy ufuncs on cache-sized blocks (several passes each, the constitutive update
one 6×6 product per phase and block, never a loop over voxels). Keep OpenBLAS at one thread
(``OPENBLAS_NUM_THREADS=1`` before importing numpy): its threads spin against FFTW's. The CG iterate itself is not
stored (unless the fields are asked for): ``⟨σ⟩`` is accumulated from the averages of ``C : p_k`` (read from the
zero frequency of the transform that is needed anyway), and ``⟨p, G[C:p]⟩ = ⟨p, C:p⟩`` (``p`` is in the range of
``G``) is summed during the constitutive pass.

``"pcg"``: per iteration one fused pass applies the hexahedron stencil ``K p = Bᵀ C B p`` voxel plane by voxel
plane (and sums ``⟨p, K p⟩`` and ``⟨C B p⟩`` for ``⟨σ⟩``), one pass updates the residual, one batched FFT pair
of the 3 displacement components wraps the Fourier kernel of ``(Bᵀ B)⁻¹`` (which also returns ``rᵀ z`` by
Parseval), and one pass updates the search direction. Its arrays are about 12.5·8·N³ bytes (``"cg"``: 26·8·N³).
"""

from __future__ import annotations

import logging
import resource
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pyfftw

from foambase.errors import ComputationError, InputError, NotConvergedError
from foambase.mpi import on_every_rank
from foambase.threads import cpu_count
from homogenization import _native, _nodal
from homogenization.result import HomogenizationResult
from homogenization.tensors import check_stiffness, closest_isotropic, mandel_to_voigt, voigt_to_mandel

__all__ = [
    "DISCRETIZATIONS",
    "SCHEMES",
    "FFTConvergenceError",
    "ReferenceMedium",
    "homogenize_fft",
    "SingularStiffnessError",
    "reference_medium",
    "wave_directions",
]

logger = logging.getLogger(__name__)

SCHEMES = ("cg", "basic", "pcg")
DISCRETIZATIONS = ("rotated", "spectral", "hex8")
#: The discretizations solved for nodal displacements (``scheme="pcg"``): trilinear voxels, one or 2×2×2 points.
NODAL = ("rotated", "hex8")
DEFAULT_MAXITER = {"cg": 1000, "basic": 5000, "pcg": 1000}

_SQRT2 = np.sqrt(2.0)
_MANDEL = np.array([1.0, 1.0, 1.0, _SQRT2, _SQRT2, _SQRT2])  # Voigt (engineering) strain → Mandel: divide
_ONES = np.ones(6)
#: ``Mandel = a/N³ · GREEN_TO_MANDEL ⊙ (what _Workspace.green leaves in the spectrum, transformed back)``
GREEN_TO_MANDEL = np.array([2.0, 2.0, 2.0, _SQRT2, _SQRT2, _SQRT2])
_BLOCK_VOXELS = 2**15  # voxels per block of planes: the block's temporaries stay in L2/L3 cache


class FFTConvergenceError(NotConvergedError):
    """The FFT solver did not reach ``tol`` within ``maxiter`` (or broke down); carries the residual history."""

    def __init__(self, message: str, case: int, residuals: list[float]):
        super().__init__(message)
        self.case = case
        self.residuals = residuals

    def __reduce__(self):
        # picklable across processes (multiprocessing, the benchmark's child processes)
        return type(self), (self.args[0], self.case, self.residuals)


class SingularStiffnessError(ComputationError):
    """The homogenized stiffness is singular or not positive definite: the solid does not percolate.

    Raised by :func:`homogenize_fft` (unless ``allow_singular=True``) when an image with a void phase gives a C
    whose smallest eigenvalue (Mandel form) is at most :data:`SINGULAR_RTOL` ``× tol ×`` the largest eigenvalue of
    the stiffest phase in the image. Carries ``result``, the :class:`HomogenizationResult` that was refused.
    """

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result

    def __reduce__(self):
        return type(self), (self.args[0], self.result)


# --------------------------------------------------------------------------------------------------
# Discrete wave vectors
# --------------------------------------------------------------------------------------------------
def wave_directions(shape: tuple[int, int, int], discretization: str = "rotated",
                    box: Sequence[float] | None = None) -> np.ndarray:
    """Unit discrete wave vectors ``n = k/|k|`` on the real-FFT half spectrum, zero where ``G = 0``.

    Parameters
    ----------
    shape
        Grid ``(N1, N2, N3)``.
    discretization
        ``"spectral"``: ``k_j = 2π m_j / L_j``, with ``n = 0`` at ``m = 0`` and, on even axes, wherever some
        ``m_j = −N_j/2`` (Nyquist). ``"rotated"``: ``k_j = (2/h_j) sin(π m_j/N_j) ∏_{l≠j} cos(π m_l/N_l)``,
        with ``n = 0`` where ``|k|`` vanishes (``m = 0`` and the hourglass modes).
    box
        Lengths ``(L1, L2, L3)`` of the periodic box; voxel sizes ``h_j = L_j/N_j``. Default: the unit cube
        (``h_j = 1/N_j``). Only the ratios of the ``L_j`` matter (``n`` is a direction).

    Returns
    -------
    numpy.ndarray
        ``(3, N1, N2, N3//2 + 1)`` float64, ``m_1, m_2`` in FFT order, ``m_3 = 0 … N3//2``.

    """
    if discretization not in ("rotated", "spectral"):
        raise InputError(f"wave_directions: discretization must be 'rotated' or 'spectral', got {discretization!r}")
    N = tuple(int(s) for s in shape)
    L = _check_box(box)
    m = [np.fft.fftfreq(N[0], 1.0 / N[0]), np.fft.fftfreq(N[1], 1.0 / N[1]), np.arange(N[2] // 2 + 1.0)]
    if N[2] % 2 == 0:
        m[2][-1] = -N[2] / 2  # the rfft's last plane is the Nyquist one
    grids = np.meshgrid(*m, indexing="ij", sparse=True)
    if discretization == "spectral":
        comps = [2 * np.pi * g / L_j for g, L_j in zip(grids, L)]
        nyquist = np.zeros(grids[0].shape[:1] + grids[1].shape[1:2] + grids[2].shape[2:], dtype=bool)
        for g, n_j in zip(grids, N):
            if n_j % 2 == 0:
                nyquist = nyquist | (g == -n_j / 2)
    else:
        half = [np.pi * g / n_j for g, n_j in zip(grids, N)]
        s = [np.sin(q) for q in half]
        c = [np.cos(q) for q in half]
        inv_h = [2 * n_j / L_j for n_j, L_j in zip(N, L)]  # 2/h_j
        comps = [inv_h[0] * s[0] * c[1] * c[2], inv_h[1] * c[0] * s[1] * c[2], inv_h[2] * c[0] * c[1] * s[2]]
    k = np.empty((3, N[0], N[1], N[2] // 2 + 1))
    for j in range(3):
        k[j] = comps[j]
    norm = np.sqrt(np.einsum("j...,j...->...", k, k))
    zero = norm <= 1e-10 * norm.max() if norm.max() > 0 else np.ones_like(norm, dtype=bool)
    if discretization == "spectral":
        zero |= nyquist
    norm[zero] = 1.0
    k /= norm
    k[:, zero] = 0.0
    return k


# --------------------------------------------------------------------------------------------------
# Reference medium of the basic scheme
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReferenceMedium:
    """Isotropic reference medium ``C0 = 3κ0 J + 2μ0 K`` of the Moulinec–Suquet scheme."""

    lam: float  #: λ0
    mu: float  #: μ0
    rate: float  #: guaranteed contraction factor ``max_p ‖C0^{-1} C_p − I‖`` (energy norm of C0); < 1

    @property
    def green_coefficients(self) -> tuple[float, float]:
        """``(1/(2μ0), (λ0+μ0)/(λ0+2μ0))``: ``Γ0[τ] = (n⊗w + w⊗n)/(2μ0)``, ``w = τn − c (n·τn) n``."""
        return 1.0 / (2.0 * self.mu), (self.lam + self.mu) / (self.lam + 2.0 * self.mu)


def reference_medium(stiffnesses_mandel: Sequence[np.ndarray]) -> ReferenceMedium:
    """CrAFT's default reference medium: the average of the phases' extreme isotropic moduli.

    Each phase is bracketed by isotropic moduli ``3κ⁻ ≤ 3κ⁺`` and ``2μ⁻ ≤ 2μ⁺``: for an isotropic phase both
    equal its own ``3κ`` and ``2μ``; for an anisotropic one (e.g. a rotated TI) they are its smallest and largest
    Mandel eigenvalues ``e_min ≤ e_max`` (so ``e_min I ≤ C_p ≤ e_max I``). Then
    ``κ0 = (min κ⁻ + max κ⁺)/2``, ``μ0 = (min μ⁻ + max μ⁺)/2``, ``λ0 = κ0 − 2μ0/3`` — for isotropic phases
    the usual ``λ0 = (λ_min + λ_max)/2``, ``μ0 = (μ_min + μ_max)/2`` when the stiffer phase has both larger
    moduli. This gives ``0 < C_p < 2 C0`` for every positive definite phase, the sufficient condition for the
    fixed point to contract; ``rate`` is the resulting contraction factor.
    """
    lo, hi = [], []
    for M in stiffnesses_mandel:
        eig = np.linalg.eigvalsh(M)
        iso = closest_isotropic(mandel_to_voigt(M))
        if iso.error <= 1e-12:
            t3k, t2m = iso.E / (1 - 2 * iso.nu), iso.E / (1 + iso.nu)  # 3κ, 2μ
            lo.append((t3k, t2m))
            hi.append((t3k, t2m))
        else:
            lo.append((eig[0], eig[0]))
            hi.append((eig[-1], eig[-1]))
    lo, hi = np.array(lo), np.array(hi)
    t3k0, t2m0 = 0.5 * (lo.min(axis=0) + hi.max(axis=0))
    J = np.zeros((6, 6))
    J[:3, :3] = 1.0 / 3.0
    C0 = t3k0 * J + t2m0 * (np.eye(6) - J)
    L = np.linalg.cholesky(np.linalg.inv(C0))
    rate = max(np.abs(np.linalg.eigvalsh(L.T @ M @ L) - 1.0).max() for M in stiffnesses_mandel)
    mu0 = t2m0 / 2.0
    return ReferenceMedium(lam=float(t3k0 / 3.0 - 2.0 * mu0 / 3.0), mu=float(mu0), rate=float(rate))


# --------------------------------------------------------------------------------------------------
# The solver's workspace: FFT plans, work arrays, blocked kernels
# --------------------------------------------------------------------------------------------------
class _Workspace:
    """Planned FFTs, the preallocated ``N³`` arrays and block-wise kernels on ``threads`` threads.

    ``real`` (6, N1, N2, N3) and ``hat`` (6, N1, N2, N3//2+1) are the FFT buffers: ``forward`` maps ``real`` to
    ``hat``, ``backward`` maps ``hat`` to ``real`` (both unnormalised; ``backward`` destroys ``hat``).

    Representations, chosen so that no pass is spent on rescaling: strains (CG vectors, ``ε``) are Mandel;
    :meth:`constitutive` writes the stress as tensor components ``σ_ij`` (= Voigt stress), which is what
    :meth:`green` reads; :meth:`green` leaves ``n_i w_i`` (diagonal) and ``n_i w_j + n_j w_i`` (shear) in ``hat``,
    so after ``backward`` the Mandel field is ``(a/N³) · GREEN_TO_MANDEL ⊙ real`` — a per-component factor that
    the callers fold into their :meth:`axpy` coefficients.
    """

    def __init__(self, phases, stiffnesses, discretization, threads, n_vectors, box=None):
        self.shape = phases.shape
        N1, N2, N3 = self.shape
        self.size = N1 * N2 * N3
        t0 = time.perf_counter()
        self.real = pyfftw.empty_aligned((6, N1, N2, N3), dtype=np.float64)
        self.hat = pyfftw.empty_aligned((6, N1, N2, N3 // 2 + 1), dtype=np.complex128)
        self.forward = pyfftw.FFTW(self.real, self.hat, axes=(1, 2, 3), direction="FFTW_FORWARD",
                                   flags=("FFTW_MEASURE",), threads=threads)
        self.backward = pyfftw.FFTW(self.hat, self.real, axes=(1, 2, 3), direction="FFTW_BACKWARD",
                                    flags=("FFTW_MEASURE", "FFTW_DESTROY_INPUT"), threads=threads)
        self.plan_s = time.perf_counter() - t0
        self.fft_s = 0.0
        self.fft_calls = 0
        self.native = _native.load()
        if self.native is not None:
            self.n = wave_directions(self.shape, discretization, box)
        else:
            # n repeated along the last axis, so that the numpy Fourier kernel runs on float64 views of the
            # complex spectrum ((re, im) pairs) without complex × real casting.
            self.n2 = np.repeat(wave_directions(self.shape, discretization, box), 2, axis=-1)
        self.vectors = [np.empty((6, N1, N2, N3)) for _ in range(n_vectors)]
        # Constitutive update σ = C_b ε + Σ_{p≠b} m_p (C_p − C_b) ε, b = the most frequent phase (no mask needed);
        # the matrices map Mandel strain to tensor stress components.
        ids, counts = np.unique(phases, return_counts=True)
        self.fractions = {int(p): c / self.size for p, c in zip(ids, counts)}
        base = int(ids[np.argmax(counts)])
        to_tensor = {p: stiffnesses[int(p)] / _MANDEL[:, None] for p in ids}
        if self.native is not None:  # the C kernel reads the phase id and its matrix voxel by voxel
            self.phase = np.ascontiguousarray(phases, dtype=np.int32)
            self.tables = np.zeros((int(ids.max()) + 1, 6, 6))
            for p in ids:
                self.tables[p] = to_tensor[p]
            self.base, self.jumps = None, []
        else:
            self.base = to_tensor[base] if np.any(to_tensor[base]) else None
            self.jumps = [(to_tensor[p] - (0.0 if self.base is None else self.base),
                           (phases == p).astype(np.float64)) for p in ids if p != base]
        # Blocks of whole planes along axis 1, split into one contiguous run per thread.
        per_block = max(1, min(_BLOCK_VOXELS // (N2 * N3), -(-N1 // threads)))
        blocks = [(i, min(i + per_block, N1)) for i in range(0, N1, per_block)]
        self.groups = [[blocks[i] for i in g] for g in np.array_split(np.arange(len(blocks)), threads) if len(g)]
        B, H = per_block, N3 // 2 + 1
        self.scratch = [dict(v=np.empty((3, B, N2, 2 * H)), t=np.empty((B, N2, 2 * H)),
                             s=np.empty((B, N2, 2 * H)), r=np.empty((6, B * N2 * N3)))
                        for _ in self.groups]
        self.pool = ThreadPoolExecutor(len(self.groups)) if len(self.groups) > 1 else None
        # Parseval on the half spectrum: planes m3 = 0 (and N3/2 if N3 is even) count once, the others twice.
        self.single_planes = [slice(0, 2)] + ([slice(2 * H - 2, 2 * H)] if N3 % 2 == 0 and H > 1 else [])

    @property
    def nbytes(self) -> int:
        """Bytes held by the ``N³`` work arrays (FFT buffers, wave vectors, vectors, masks, block scratch)."""
        arrays = [self.real, self.hat, *self.vectors, *(m for _, m in self.jumps)]
        arrays += [self.n, self.phase, self.tables] if self.native is not None else [self.n2]
        arrays += [a for s in self.scratch for a in s.values()]
        return int(sum(a.nbytes for a in arrays))

    def _pointer(self, array: np.ndarray, offset: int = 0, ctype: str = "double *"):
        """Pointer (cffi) to ``array``'s element ``offset``; the kernels index it as a C-contiguous array."""
        if not array.flags.c_contiguous:
            raise ValueError("the FFT solver's C kernels need C-contiguous work arrays")
        return self.native[0].cast(ctype, array.ctypes.data) + offset

    def close(self):
        """Stop the worker threads."""
        if self.pool is not None:
            self.pool.shutdown()

    def run(self, kernel: Callable) -> float:
        """Run ``kernel(i0, i1, scratch) -> float | None`` on every block (one thread per group); sum results."""
        def group(k):
            total = 0.0
            for i0, i1 in self.groups[k]:
                total += kernel(i0, i1, self.scratch[k]) or 0.0
            return total
        if self.pool is None:
            return group(0)
        return float(sum(self.pool.map(group, range(len(self.groups)))))

    # ---------------------------------------------------------------------------------------------
    def fft(self):
        """``hat ← FFT(real)``."""
        t0 = time.perf_counter()
        self.forward.execute()
        self.fft_s += time.perf_counter() - t0
        self.fft_calls += 1

    def ifft(self):
        """``real ← N³ · IFFT(hat)`` (unnormalised; ``hat`` is destroyed)."""
        t0 = time.perf_counter()
        self.backward.execute()
        self.fft_s += time.perf_counter() - t0
        self.fft_calls += 1

    def mean_stress(self) -> np.ndarray:
        """``⟨σ⟩`` (tensor components = Voigt stress) of the field just transformed: ``hat(ξ = 0)/N³``."""
        return self.hat[:, 0, 0, 0].real / self.size

    def constitutive(self, out: np.ndarray, strain: np.ndarray, update: tuple | None = None) -> float:
        """``out ← C(x) : strain`` (tensor stress from Mandel strain); returns ``⟨strain, C : strain⟩`` (Mandel).

        With ``update = (r, β)`` the strain is first updated in place, ``strain ← r + β strain`` (the CG search
        direction), in the same pass over the blocks.
        """
        N2N3 = self.shape[1] * self.shape[2]
        weights = _MANDEL  # ⟨ε_M, σ_M⟩ = Σ_c √2^[c shear] ε_M[c] σ_t[c]
        if self.native is not None:
            lib, ptr = self.native[1], self._pointer
            r, beta = update if update is not None else (strain, 0.0)

            def native(i0, i1, _):
                o = i0 * N2N3
                return lib.ff_constitutive((i1 - i0) * N2N3, self.size, ptr(strain, o), ptr(r, o), beta,
                                           update is not None, ptr(self.phase, o, "int32_t *"),
                                           len(self.tables), ptr(self.tables), ptr(weights), ptr(out, o))
            return self.run(native)

        def kernel(i0, i1, scratch):
            if update is not None:
                blk = strain[:, i0:i1]
                blk *= update[1]
                blk += update[0][:, i0:i1]
            eps = strain[:, i0:i1].reshape(6, -1)
            sig = out[:, i0:i1].reshape(6, -1)
            tmp = scratch["r"][:, : eps.shape[1]]
            empty = self.base is None
            if not empty:
                np.matmul(self.base, eps, out=sig)
            for dC, mask in self.jumps:
                m = mask[i0:i1].reshape(1, (i1 - i0) * N2N3)
                np.matmul(dC, eps, out=sig if empty else tmp)
                if empty:
                    sig *= m
                    empty = False
                else:
                    tmp *= m
                    sig += tmp
            if empty:  # every phase present is void
                sig[...] = 0.0
            return sum(weights[c] * float(np.vdot(eps[c], sig[c])) for c in range(6))

        return self.run(kernel)

    def green(self, c: float, residual: bool = False) -> float:
        """In place on ``hat`` (``τ̂``, tensor components): ``hat ← n ⊗ w + w ⊗ n``, ``w = τ̂ n − c (n·τ̂n) n``.

        The result is stored as ``n_i w_i`` (11, 22, 33) and ``n_i w_j + n_j w_i`` (23, 13, 12).
        ``c = ½`` gives the projection ``G[τ] = 2 sym(n ⊗ w)``; ``c = (λ0+μ0)/(λ0+2μ0)`` gives ``2μ0 Γ0[τ]``.
        The Mandel field is ``a · GREEN_TO_MANDEL ⊙ hat`` (``a = 1`` for ``G``, ``1/(2μ0)`` for ``Γ0``).
        With ``residual=True`` also returns ``Σ_x |G[τ](x)|² = N⁻³ Σ_ξ (2|τ̂n|² − |n·τ̂n|²)`` over the full
        spectrum (Parseval).
        """
        if self.native is not None:
            lib, ptr = self.native[1], self._pointer
            N2, H = self.shape[1], self.shape[2] // 2 + 1
            stride, nstride = 2 * self.shape[0] * N2 * H, self.shape[0] * N2 * H
            nyquist = self.shape[2] % 2 == 0 and H > 1

            def native(i0, i1, _):
                o = i0 * N2 * H
                return lib.ff_green((i1 - i0) * N2 * H, stride, ptr(self.hat, 2 * o), nstride, ptr(self.n, o),
                                    c, residual, H, nyquist)
            total = self.run(native)
            return total / self.size if residual else 0.0
        hat, n = self.hat.view(np.float64), self.n2  # (re, im) pairs; n is real, so it acts on both alike
        single = self.single_planes

        def kernel(i0, i1, scratch):
            T = hat[:, i0:i1]
            n0, n1, n2 = n[0, i0:i1], n[1, i0:i1], n[2, i0:i1]
            m = i1 - i0
            v, t, s = scratch["v"][:, :m], scratch["t"][:m], scratch["s"][:m]
            # v = τ n, τ = [[T0, T5, T4], [T5, T1, T3], [T4, T3, T2]]
            for i, (ja, jb, jc) in enumerate(((0, 5, 4), (5, 1, 3), (4, 3, 2))):
                np.multiply(T[ja], n0, out=v[i])
                np.multiply(T[jb], n1, out=t)
                v[i] += t
                np.multiply(T[jc], n2, out=t)
                v[i] += t
            np.multiply(v[0], n0, out=s)
            np.multiply(v[1], n1, out=t)
            s += t
            np.multiply(v[2], n2, out=t)
            s += t
            out = None
            if residual:  # half spectrum: planes m3 = 0 (and Nyquist) once, the others twice
                out = 2.0 * (2.0 * np.vdot(v, v) - np.vdot(s, s))
                for k in single:
                    out -= 2.0 * np.vdot(v[..., k], v[..., k]) - np.vdot(s[..., k], s[..., k])
            s *= c
            for i, ni in enumerate((n0, n1, n2)):  # w = v − c s n
                np.multiply(s, ni, out=t)
                v[i] -= t
            for i, ni in enumerate((n0, n1, n2)):
                np.multiply(v[i], ni, out=T[i])
            for I, (i, j) in zip((3, 4, 5), ((1, 2), (0, 2), (0, 1))):
                np.multiply(v[j], (n0, n1, n2)[i], out=T[I])
                np.multiply(v[i], (n0, n1, n2)[j], out=t)
                T[I] += t
            return out

        total = self.run(kernel)
        return total / self.size if residual else 0.0

    def dot(self, x: np.ndarray, y: np.ndarray, weights: np.ndarray = _ONES) -> float:
        """``Σ_x Σ_c weights[c] x_c y_c`` over all voxels."""
        def kernel(i0, i1, _):
            return sum(weights[c] * float(np.vdot(x[c, i0:i1], y[c, i0:i1])) for c in range(6))
        return self.run(kernel)

    def axpy(self, alpha: np.ndarray, x: np.ndarray, y: np.ndarray, norm: bool = False) -> float:
        """``y_c ← y_c + α_c x_c`` (one coefficient per component); returns ``Σ y·y`` if ``norm``, else 0."""
        N2N3 = self.shape[1] * self.shape[2]
        if self.native is not None:
            lib, ptr = self.native[1], self._pointer
            coefficients = np.ascontiguousarray(alpha, dtype=float)

            def native(i0, i1, _):
                o = i0 * N2N3
                return lib.ff_axpy((i1 - i0) * N2N3, self.size, ptr(coefficients), ptr(x, o), ptr(y, o), norm)
            return self.run(native)
        alpha = np.asarray(alpha, dtype=float).reshape(6, 1, 1, 1)

        def kernel(i0, i1, scratch):
            ys = y[:, i0:i1]
            tmp = scratch["r"][:, : (i1 - i0) * N2N3].reshape(ys.shape)
            np.multiply(x[:, i0:i1], alpha, out=tmp)
            ys += tmp
            return sum(float(np.vdot(ys[c], ys[c])) for c in range(6)) if norm else None
        return self.run(kernel)


# --------------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------------
def _check_phases(phases) -> np.ndarray:
    phases = np.asarray(phases)
    if phases.ndim != 3:
        raise InputError(f"phases must be a 3-D (N1, N2, N3) image of phase ids, got shape {phases.shape}")
    if min(phases.shape) < 1:
        raise InputError(f"phases must have at least one voxel along each axis, got shape {phases.shape}")
    if phases.dtype == bool:
        return phases.astype(np.intp)
    if not np.issubdtype(phases.dtype, np.integer):
        raise InputError(f"phases must hold integer phase ids (or bool), got dtype {phases.dtype}")
    if phases.min() < 0:
        raise InputError(f"phase ids must be >= 0, got {int(phases.min())}")
    return phases


def _binary_exponent(x: float) -> int:
    """``e`` with ``2**(e-1) <= x < 2**e`` (``x > 0``): multiplying by ``2**(1-e)`` brings x into [1, 2) exactly."""
    return int(np.frexp(x)[1])


def _check_materials(materials, ids) -> tuple[dict[int, np.ndarray], int]:
    """The phases' stiffnesses scaled by ``2**k`` so that the largest entry lies in [1, 2), and ``k``.

    The solver works on the scaled stiffnesses: its squared norms neither overflow nor underflow whatever the
    unit of the moduli (1e200 or 1e-170), and a power of two changes no digit, so ``C`` is the same (bit for bit
    when no intermediate is subnormal) as for the stiffness in any other unit, times that unit.
    """
    if isinstance(materials, Mapping):
        available = {int(p): materials[p] for p in materials}
    else:
        available = dict(enumerate(materials))
    missing = [int(p) for p in ids if int(p) not in available]
    if missing:
        raise InputError(f"phase ids {missing} occur in the image but have no material "
                         f"(materials given for ids {sorted(available)})")
    raw = {}
    for p in map(int, ids):
        try:
            C = np.asarray(available[p], dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"materials[{p}] must be a 6×6 Voigt stiffness of numbers, "
                             f"got {available[p]!r:.80}") from exc
        if C.shape != (6, 6):
            raise InputError(f"materials[{p}] must be a 6×6 Voigt stiffness, got shape {C.shape}")
        if not np.all(np.isfinite(C)):
            raise InputError(f"materials[{p}] has non-finite entries: {C[~np.isfinite(C)][:3].tolist()}")
        raw[p] = C
    largest = max(float(np.abs(C).max()) for C in raw.values())
    if largest == 0.0:
        raise InputError(f"every phase in the image ({sorted(raw)}) has zero stiffness (void): nothing carries "
                         "load; the image needs a solid phase with a positive definite stiffness")
    if largest < np.finfo(float).tiny:
        raise InputError(f"materials: the largest stiffness entry {largest:.3g} is a subnormal double (below "
                         f"{np.finfo(float).tiny:.3g}) and has lost its precision; give the moduli in another unit")
    k = 1 - _binary_exponent(largest)
    out = {}
    for p, C in raw.items():
        C = np.ldexp(C, k)
        try:
            check_stiffness(C, allow_zero=True, name=f"materials[{p}]")
        except InputError as exc:
            raise type(exc)(f"{exc}{'' if k == 0 else f' (values scaled by 2**{k})'}") from exc
        out[p] = 0.5 * (C + C.T)
    return out, k


def _check_box(box) -> tuple[float, float, float]:
    """``(L1, L2, L3)`` as floats (the unit cube if ``box`` is None), or an InputError naming the bad value."""
    if box is None:
        return (1.0, 1.0, 1.0)
    try:
        L = tuple(float(b) for b in box)
    except (TypeError, ValueError):
        raise InputError(f"box must be three positive lengths (L1, L2, L3), got {box!r}") from None
    if len(L) != 3 or not all(np.isfinite(b) and b > 0.0 for b in L):
        raise InputError(f"box must be three positive finite lengths (L1, L2, L3), got {box!r}")
    return L


def _check_macro_strains(macro_strains) -> np.ndarray:
    if macro_strains is None:
        return np.eye(6)
    E = np.asarray(macro_strains, dtype=float)
    if E.ndim == 1:
        E = E[None]
    if E.ndim != 2 or E.shape[1] != 6 or E.shape[0] == 0:
        raise InputError(f"macro_strains must be (n_cases, 6) Voigt strains, got shape {np.shape(macro_strains)}")
    if not np.all(np.isfinite(E)):
        raise InputError("macro_strains must be finite")
    zero = [i for i, row in enumerate(E) if not np.any(row)]
    if zero:
        raise InputError(f"macro_strains[{zero[0]}] is zero (load case(s) {zero} of {E.shape[0]}): a zero macroscopic "
                         "strain has no response to homogenize; every load case needs a non-zero strain")
    return E


def _check_checkpoints(checkpoints, tol: float) -> list[float]:
    marks = sorted({float(t) for t in checkpoints}, reverse=True)
    bad = [t for t in marks if not (np.isfinite(t) and tol <= t < 1.0)]
    if bad:
        raise InputError(f"checkpoints must satisfy tol = {tol:g} <= t < 1, got {bad}")
    return marks


def _stiffness_columns(strains: np.ndarray, mean_stress: np.ndarray) -> np.ndarray:
    """Raw Voigt C: column J is ⟨σ⟩/E_J of the case whose strain is a multiple of unit strain J (else NaN)."""
    C_raw = np.full((6, 6), np.nan)
    for E_voigt, sigma in zip(strains, mean_stress):
        nonzero = np.flatnonzero(E_voigt)
        if len(nonzero) == 1:
            C_raw[:, nonzero[0]] = sigma / E_voigt[nonzero[0]]
    return C_raw


# --------------------------------------------------------------------------------------------------
# The schemes: each solves one load case, returns (⟨σ⟩ Voigt, residual history, converged, message) and calls
# report(iteration, residual, ⟨σ⟩ of the current iterate) after every iteration (and at iteration 0)
# --------------------------------------------------------------------------------------------------
_ROUNDOFF = 1e3 * np.finfo(float).eps


def _solve_cg(ws: _Workspace, E: np.ndarray, tol: float, maxiter: int, report: Callable, keep: bool):
    r, p = ws.vectors[0], ws.vectors[1]
    x = ws.vectors[2] if keep else None
    work = ws.real
    to_mandel = GREEN_TO_MANDEL / ws.size  # work → Mandel G[·] after ifft
    p[...] = E[:, None, None, None]
    ws.constitutive(work, p)  # σ_E = C : E
    load = np.sqrt(ws.dot(work, work, _MANDEL**2))
    ws.fft()
    mean = ws.mean_stress()
    ws.green(0.5)
    ws.ifft()
    np.multiply(work, -to_mandel[:, None, None, None], out=r)  # r_0 = −G[C : E]
    if x is not None:
        x[...] = 0.0
    rr = ws.dot(r, r)
    r0 = np.sqrt(rr)
    if r0 <= _ROUNDOFF * load:
        report(0, 0.0, mean)
        return mean, [0.0], True, ""
    history = [1.0]
    report(0, 1.0, mean)
    beta = 0.0  # p still holds E: the first direction is p = r + 0·p = r
    for it in range(1, maxiter + 1):
        pAp = ws.constitutive(work, p, update=(r, beta))  # p ← r + βp; ⟨p, G[C:p]⟩ = ⟨p, C:p⟩ since p = G[p]
        if not np.isfinite(pAp):
            raise ComputationError(f"CG: <p, C:p> = {pAp} at iteration {it}: the fields overflowed or hold NaN")
        if pAp <= 0.0:
            return mean, history, False, f"CG breakdown at iteration {it}: <p, C:p> = {pAp:.3g}"
        ws.fft()
        mean_p = ws.mean_stress()
        ws.green(0.5)
        ws.ifft()  # work ∝ G[C : p]
        alpha = rr / pAp
        mean += alpha * mean_p
        if x is not None:
            ws.axpy(np.full(6, alpha), p, x)  # x ← x + α p
        rr_new = ws.axpy(-alpha * to_mandel, work, r, norm=True)
        history.append(float(np.sqrt(rr_new) / r0))
        report(it, history[-1], mean)
        if history[-1] <= tol:
            return mean, history, True, ""
        beta = rr_new / rr
        rr = rr_new
    return mean, history, False, f"CG did not reach tol in maxiter = {maxiter} iterations"


def _solve_basic(ws: _Workspace, E: np.ndarray, tol: float, maxiter: int, report: Callable, ref: ReferenceMedium):
    eps = ws.vectors[0]
    work = ws.real
    a, c = ref.green_coefficients
    update = -a / ws.size * GREEN_TO_MANDEL  # ε ← ε − Γ0[σ]
    eps[...] = E[:, None, None, None]
    history: list[float] = []
    r0 = load = 0.0
    for it in range(maxiter + 1):
        ws.constitutive(work, eps)
        if it == 0:
            load = np.sqrt(ws.dot(work, work, _MANDEL**2))
        ws.fft()
        mean = ws.mean_stress()
        g2 = ws.green(c, residual=True)  # hat ∝ Γ0[σ̂]; g2 = ‖G[σ]‖²
        if it == 0:
            r0 = np.sqrt(max(g2, 0.0))
            if r0 <= _ROUNDOFF * load:
                report(0, 0.0, mean)
                return mean, [0.0], True, ""
        history.append(float(np.sqrt(max(g2, 0.0)) / r0))
        report(it, history[-1], mean)
        if history[-1] <= tol:
            return mean, history, True, ""
        if not np.isfinite(history[-1]) or history[-1] > 1e6:
            return mean, history, False, f"basic scheme diverged at iteration {it}"
        if it == maxiter:
            break
        ws.ifft()
        ws.axpy(update, work, eps)
    return mean, history, False, (f"basic scheme did not reach tol in maxiter = {maxiter} iterations "
                                  f"(contraction factor of the reference medium {ref.rate:.6g})")


# --------------------------------------------------------------------------------------------------
# Public entry point
# --------------------------------------------------------------------------------------------------
def homogenize_fft(
    phases: np.ndarray,
    materials: Sequence[np.ndarray] | Mapping[int, np.ndarray],
    *,
    scheme: str | None = None,
    discretization: str = "rotated",
    box: Sequence[float] | None = None,
    tol: float = 1e-6,
    maxiter: int | None = None,
    threads: int | None = None,
    macro_strains: np.ndarray | None = None,
    callback: Callable[[int, int, float], None] | None = None,
    checkpoints: Sequence[float] = (),
    raise_on_failure: bool = True,
    return_fields: bool = False,
    comm=None,
    slab: bool = False,
    allow_singular: bool = False,
) -> HomogenizationResult:
    """Homogenized stiffness of a periodic voxel image by FFT (see the module docstring for the method).

    Parameters
    ----------
    phases
        ``(N1, N2, N3)`` integer (or bool) image of phase ids; array axis *a* is coordinate ``x_a`` and voxel
        ``[i, j, k]`` is centred at ``((i+½) h1, (j+½) h2, (k+½) h3)`` in the periodic box, ``h_a = L_a/N_a``.
    materials
        ``materials[p]`` is the 6×6 Voigt stiffness of phase ``p`` (a list indexed by phase id or a dict);
        symmetric positive definite, or exactly zero for a void phase. Ids absent from the image are ignored.
    scheme
        ``"pcg"`` (default with ``"rotated"``): conjugate gradients on the nodal displacements of the rotated
        discretization, preconditioned by the Green operator (``homogenization._nodal``); same iterates and C as
        ``"cg"`` at half the FFT work. ``"cg"`` (default with ``"spectral"``): Galerkin + conjugate gradients on
        the strain. ``"basic"``: Moulinec–Suquet fixed point with :func:`reference_medium` (refuses a
        zero-stiffness phase).
    discretization
        ``"rotated"`` (Willot, default) or ``"spectral"`` (Moulinec–Suquet), see :func:`wave_directions`;
        ``"hex8"``: fully integrated trilinear voxels, ``scheme="pcg"`` only (the module docstring).
    box
        Lengths ``(L1, L2, L3)`` of the periodic box (any unit: only their ratios matter); default the unit cube,
        ``h_a = 1/N_a``. For an RVE box of lengths ``L`` with cubic voxels pass ``box=L`` with
        ``N_a ∝ L_a``, or simply ``box=phases.shape``. Non-cubic voxels are allowed (both discretizations are
        defined for any ``h_a``); they are what the default gives for a non-cubic grid.
    tol
        Stop when ``‖G[σ]‖ / ‖G[C:E]‖ ≤ tol`` (``0 < tol < 1``).
    maxiter
        Iterations per load case; default 1000 for ``cg``, 5000 for ``basic``.
    threads
        FFTW and block-kernel threads; default: the CPUs this process may run on (distributed: divided by the
        number of ranks on the node).
    macro_strains
        ``(n_cases, 6)`` Voigt macroscopic strains (engineering shear); default the six unit strains. Column *J*
        of ``C`` is ``⟨σ⟩/E_J`` of the case whose strain is a multiple of unit strain *J*; columns of ``C`` with
        no such case are NaN. ``info["mean_stress"]`` holds ``⟨σ⟩`` (Voigt) of every case.
    callback
        ``callback(case, iteration, residual)`` after every iteration (and at iteration 0).
    checkpoints
        Looser tolerances (``tol ≤ t < 1``) at which to record the result a run with ``tol = t`` would return:
        the iterates of a run pass through exactly the states a looser run stops at, so one run at the tightest
        tolerance gives a whole tolerance study. ``info["checkpoints"]`` lists, loosest first, ``{"tol", "C",
        "iterations", "wall_s", "converged"}``: ``C`` symmetrized like ``result.C``, ``iterations`` per load
        case, ``wall_s`` the set-up plus each load case's time up to its first iteration with residual ≤ t (or
        its whole time if it never got there: then ``converged`` is False).
    raise_on_failure
        If True (default) non-convergence raises :class:`FFTConvergenceError`; if False the result comes back
        with ``converged=False`` and the residual histories.
    return_fields
        Also return ``fields = {"strain", "stress"}``, each ``(n_cases, 6, N1, N2, N3)`` Voigt (distributed:
        this rank's planes). With ``"pcg"`` the strain of a voxel whose 8 nodes all touch only void is whatever
        the nodal solution gives there (the problem does not determine it; its stress is zero).
    comm
        mpi4py communicator: with more than one rank the image is distributed over the ranks in slabs of planes
        along axis 0 (:func:`slab_planes`), the FFTs by mpi4py-fft; scheme ``"pcg"``, discretization
        ``"rotated"`` or ``"hex8"``. Every rank returns the same result (``info`` adds ``ranks``, ``planes``,
        ``work_bytes_per_rank``, ``peak_rss_bytes_per_rank``). At most ``min(N1, N3//2 + 1)`` ranks
        (the spectrum is split along its last axis); any rank count up to that works (uneven slabs). Call it on
        every rank of ``comm``.
    slab
        Distributed mode only: ``phases`` is this rank's slab ``phases[slice(*slab_planes(N1, comm))]`` of the
        global image, for images too large for one rank; default: every rank passes the same full image.
    allow_singular
        If False (default), an image with a zero-stiffness (void) phase whose converged C is singular or not
        positive definite raises :class:`SingularStiffnessError`: the smallest eigenvalue of C (Mandel form) is
        at most ``SINGULAR_RTOL × tol`` times the largest eigenvalue of the stiffest phase in the image, i.e. zero
        or negative up to round-off (the solid does not percolate: isolated blocks, or layers separated by
        void). Checked when all six columns of C are solved and every load case converged. True returns such a C
        (an image that deliberately does not percolate).

    Returns
    -------
    HomogenizationResult
        ``method="fft"``; ``info`` holds the settings, ``shape``, stopping criterion, reference medium (basic),
        timings (``plan_s``; ``fft_s`` over all transforms; ``time_per_iteration_s`` and
        ``fft_time_per_iteration_s``: wall and FFT time of the load-case solves, their set-up included, divided by
        the total number of iterations; ``iteration_to_fft_ratio``), ``work_bytes`` (the solver's ``N³`` arrays,
        exact) and ``peak_rss_bytes`` (process peak RSS from ``getrusage``, an upper bound that includes
        everything else the process holds).

    """
    t_start = time.perf_counter()
    comm = comm if comm is not None and comm.Get_size() > 1 else None
    settings = dict(scheme=scheme, discretization=discretization, box=box, tol=tol, maxiter=maxiter, threads=threads,
                    macro_strains=macro_strains, checkpoints=checkpoints, return_fields=return_fields)
    if comm is None:
        run = _check_inputs(phases, materials, **settings)
    else:
        run = _collective(comm, lambda: _check_inputs_distributed(phases, materials, comm, slab, **settings),
                          "checking the inputs")
    ws = _collective(comm, lambda: _make_workspace(run), "setting up the FFT work arrays")
    logger.info("FFT homogenization: %s/%s on %s, %d threads, %.1f MB of work arrays%s, plan %.2f s",
                run.scheme, run.discretization, run.shape, run.threads, ws.nbytes / 1e6,
                "" if comm is None else f" per rank ({comm.Get_size()} ranks)", ws.plan_s)
    marks = _Checkpoints(run.marks)
    setup_s = time.perf_counter() - t_start
    cases = []
    try:
        for case, E_voigt in enumerate(run.strains):
            cases.append(_solve_case(ws, run, case, E_voigt, marks, callback))
            if not cases[-1].converged and raise_on_failure:
                raise FFTConvergenceError(cases[-1].message, case, cases[-1].history)
            if not cases[-1].converged:
                logger.warning(cases[-1].message)
        stats = {"work_bytes": ws.nbytes, "plan_s": ws.plan_s, "fft_s": ws.fft_s, "fft_calls": ws.fft_calls,
                 "volume_fractions": {str(p): f for p, f in ws.fractions.items()}}
    finally:
        ws.close()
    result = _assemble_result(run, cases, stats, marks.summary(run.strains, setup_s), t_start, comm)
    if not allow_singular:
        _check_not_singular(run, result)
    return result


#: A C whose smallest eigenvalue is at most ``SINGULAR_RTOL × tol × λmax(stiffest phase)`` is refused as singular
#: (:func:`homogenize_fft`, ``allow_singular``). Every non-percolating image measured (isolated blocks, rods along
#: one axis; rotated, hex8, spectral) gives a *negative* smallest eigenvalue, −1.5e-7 … −4e-3 × tol × λmax (the
#: round-off of a zero matrix); a foam whose weakest mode is tiny but positive is kept (the coarse γ = 0.1 sample of
#: the table demo's ``--ci`` run has 2.7e-5 × tol × λmax, its G12 nearly a mechanism at that resolution; the
#: softest shipped table foam 0.025). So the bound refuses what is not positive definite, with a margin for
#: round-off, and leaves the judgement of a weak but positive C to the caller.
SINGULAR_RTOL = 1e-6


def _check_not_singular(run: _Run, result: HomogenizationResult) -> None:
    """Raise :class:`SingularStiffnessError` if an image with void gives a C that is zero within the tolerance."""
    present = [p for p, n in run.counts.items() if n > 0 and p in run.stiffness]
    void = [p for p in present if not np.any(run.stiffness[p])]
    if not void or not result.converged or not np.all(np.isfinite(result.C)):
        return  # without void C ≥ the Reuss bound > 0; a non-converged or partial C is reported otherwise
    # in the solver's scaled units (the stiffnesses times 2**scale): no overflow for moduli near the float limit
    solid_max = max(float(np.linalg.eigvalsh(run.stiffness[p]).max()) for p in present)
    eig = np.linalg.eigvalsh(voigt_to_mandel(np.ldexp(result.C, run.scale)))
    if eig.min() > SINGULAR_RTOL * run.tol * solid_max:
        return
    with np.errstate(over="ignore"):
        low, high, solid = (float(np.ldexp(v, -run.scale)) for v in (eig.min(), eig.max(), solid_max))
    raise SingularStiffnessError(
        f"the homogenized stiffness is singular or not positive definite: its smallest eigenvalue (Mandel) is "
        f"{low:.3g} = {eig.min() / solid_max:.3g} × the stiffest phase's largest ({solid:.3g}), largest "
        f"of C {high:.3g}; the solid (phases {sorted(set(present) - set(void))}, void {void}) does not "
        f"percolate — isolated pieces or layers separated by void carry no load. Pass allow_singular=True to "
        f"return such a C. C = {np.array2string(result.C, precision=4)}", result)


def slab_planes(n1: int, comm, rank: int | None = None) -> tuple[int, int]:
    """Planes ``[start, stop)`` along axis 0 that ``rank`` (default: this rank) of ``comm`` holds, for N1 = ``n1``.

    The block distribution of mpi4py-fft: the first ``n1 % size`` ranks get one plane more. With
    ``homogenize_fft(..., comm=comm, slab=True)`` each rank passes ``phases[start:stop]`` of the global image.
    """
    size = comm.Get_size()
    rank = comm.Get_rank() if rank is None else int(rank)
    q, r = divmod(int(n1), size)
    start = rank * q + min(rank, r)
    return start, start + q + (1 if rank < r else 0)


def _collective(comm, action: Callable, what: str):
    """Run ``action()`` on every rank; if it fails on any rank, raise the lowest failing rank's error on all ranks.

    Input errors are thus raised everywhere (as :class:`InputError`), before any collective work, instead of
    leaving the other ranks waiting in a collective call (:func:`foambase.mpi.on_every_rank`).
    """
    if comm is None:
        return action()
    return on_every_rank(comm, action, what)


# --------------------------------------------------------------------------------------------------
# The pieces of homogenize_fft: checked settings, one load case, checkpoints, the result
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Run:
    """The checked inputs of one :func:`homogenize_fft` call (stiffnesses in Mandel form)."""

    phases: np.ndarray
    stiffness: dict[int, np.ndarray]  #: Mandel, scaled by ``2**scale`` (largest entry in [1, 2) in Voigt)
    scheme: str
    discretization: str
    box: tuple[float, float, float]
    tol: float
    maxiter: int
    threads: int
    strains: np.ndarray  #: (n_cases, 6) Voigt macroscopic strains
    marks: list[float]  #: checkpoint tolerances, loosest first
    reference: ReferenceMedium | None  #: basic scheme only
    return_fields: bool
    shape: tuple[int, int, int] = (0, 0, 0)  #: global image shape (``phases`` holds planes ``i0 …`` of it)
    i0: int = 0  #: first plane of ``phases`` (distributed mode)
    counts: dict | None = None  #: voxels per phase id over the whole image
    comm: object = None  #: communicator of the distributed mode (None: serial)
    scale: int = 0  #: the solver's stiffnesses are the given ones times ``2**scale``

    @property
    def keep_iterate(self) -> bool:
        """CG stores its iterate only when the fields are asked for."""
        return self.return_fields and self.scheme in ("cg", "pcg")


def _make_workspace(run: _Run):
    """The scheme's work arrays and FFT plans: strain fields (cg, basic) or nodal displacements (pcg)."""
    if run.scheme != "pcg":
        return _Workspace(run.phases, run.stiffness, run.discretization, run.threads, box=run.box,
                          n_vectors={"cg": 2 + run.keep_iterate, "basic": 1}[run.scheme])
    tables = _nodal.stiffness_tables({p: run.stiffness[p] for p in run.counts})
    kind = _nodal.Hex8Workspace if run.discretization == "hex8" else _nodal.NodalWorkspace
    ws = kind(run.phases, tables, run.shape, run.box, run.threads, run.keep_iterate,
                               comm=run.comm, i0=run.i0)
    ws.fractions = {p: c / ws.size for p, c in run.counts.items()}
    return ws


def _check_inputs(phases, materials, *, scheme, discretization, box, tol, maxiter, threads, macro_strains,
                  checkpoints, return_fields) -> _Run:
    """Every argument checked (an InputError naming the bad value and what is valid) before any work."""
    phases = _check_phases(phases)
    stiff, scale = _check_materials(materials, np.unique(phases))
    if scheme is None:
        scheme = "pcg" if discretization in NODAL else "cg"
    if scheme not in SCHEMES:
        raise InputError(f"scheme must be one of {SCHEMES}, got {scheme!r}")
    if discretization not in DISCRETIZATIONS:
        raise InputError(f"discretization must be one of {DISCRETIZATIONS}, got {discretization!r}")
    if scheme == "pcg" and discretization not in NODAL:
        raise InputError(f"scheme='pcg' solves for the nodal displacements of trilinear voxels (discretizations "
                         f"{NODAL}); it cannot run discretization={discretization!r}: use scheme='cg'")
    if discretization == "hex8" and scheme != "pcg":
        raise InputError(f"discretization='hex8' (fully integrated trilinear voxels) is solved by scheme='pcg' only, "
                         f"got scheme={scheme!r}")
    if isinstance(tol, bool) or not isinstance(tol, int | float | np.integer | np.floating):
        raise InputError(f"tol must be a number, 0 < tol < 1, got {tol!r}")
    if not (np.isfinite(tol) and 0.0 < tol < 1.0):
        raise InputError(f"tol must satisfy 0 < tol < 1, got tol = {tol}")
    maxiter = DEFAULT_MAXITER[scheme] if maxiter is None else maxiter
    if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)) or maxiter < 1:
        raise InputError(f"maxiter must be a positive integer, got {maxiter!r}")
    threads = cpu_count() if threads is None else threads
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise InputError(f"threads must be a positive integer, got {threads!r}")
    L = _check_box(box)
    strains = _check_macro_strains(macro_strains)
    marks = _check_checkpoints(checkpoints, tol)
    mandel = {p: voigt_to_mandel(C) for p, C in stiff.items()}
    ref = None
    if scheme == "basic":
        void = [p for p, C in stiff.items() if not np.any(C)]
        if void:
            raise InputError(f"scheme='basic' cannot handle the zero-stiffness (void) phase(s) {void}: the "
                             "Moulinec–Suquet fixed point does not converge at infinite contrast; use scheme='cg'")
        ref = reference_medium(list(mandel.values()))
    ids, counts = np.unique(phases, return_counts=True)
    return _Run(phases=phases, stiffness=mandel, scheme=scheme, discretization=discretization, box=L, tol=tol,
                maxiter=int(maxiter), threads=int(threads), strains=strains, marks=marks, reference=ref,
                return_fields=bool(return_fields), shape=tuple(phases.shape), scale=scale,
                counts={int(p): int(c) for p, c in zip(ids, counts)})


def _check_inputs_distributed(phases, materials, comm, slab, **settings) -> _Run:
    """:func:`_check_inputs` for one image distributed over ``comm`` (planes along axis 0), scheme ``pcg`` only.

    ``slab=False``: every rank passes the same full image and keeps its planes; ``slab=True``: every rank passes
    its planes ``slab_planes(N1, comm)`` of the global image. The phase ids and their counts are global.
    """
    import dataclasses

    from mpi4py import MPI

    size = comm.Get_size()
    scheme, discretization = settings["scheme"], settings["discretization"]
    # 1. checks of this rank's own arguments, gathered before any other collective call (a rank that raised here
    #    alone would leave the others waiting in the next one)
    def own():
        if (scheme or "pcg") != "pcg" or discretization not in NODAL:
            raise InputError(f"distributed mode (comm with {size} ranks) runs scheme='pcg', "
                             f"discretization 'rotated' or 'hex8'; got scheme={scheme!r}, "
                             f"discretization={discretization!r}")
        image = np.asarray(phases)
        if slab and image.ndim == 3 and image.shape[0] == 0:  # an empty slab: too many ranks (below)
            return image
        try:
            return _check_phases(image)
        except InputError as exc:
            raise InputError(f"{exc} (rank {comm.Get_rank()})") from exc
    phases = on_every_rank(comm, own, "checking the phase image")
    # 2. global checks: every rank reaches the same verdict
    settings = dict(settings, scheme="pcg")
    if settings["threads"] is None:  # the ranks on one node share its CPUs
        node = comm.Split_type(MPI.COMM_TYPE_SHARED)
        settings["threads"] = max(1, cpu_count() // node.Get_size())
        node.Free()
    shapes = comm.allgather(tuple(int(n) for n in phases.shape))
    if slab:
        if any(s[1:] != shapes[0][1:] for s in shapes):
            raise InputError(f"slab=True: the ranks' slabs must share N2, N3; got shapes {shapes}")
        shape = (sum(s[0] for s in shapes),) + tuple(shapes[0][1:])
    else:
        if any(s != shapes[0] for s in shapes):
            raise InputError(f"every rank must pass the same full image (or use slab=True); got shapes {shapes}")
        shape = tuple(shapes[0])
    most = min(shape[0], shape[2] // 2 + 1)
    if size > most:
        raise InputError(f"distributed mode needs at most min(N1, N3//2 + 1) = {most} ranks for an image of shape "
                         f"{shape} (one plane per rank in physical space along axis 0, in Fourier space along axis "
                         f"2); got {size} ranks")
    i0, i1 = slab_planes(shape[0], comm)
    if slab:
        expected = [int(np.diff(slab_planes(shape[0], comm, r))[0]) for r in range(size)]
        if [s[0] for s in shapes] != expected:
            raise InputError(f"slab=True: rank r must pass planes slab_planes(N1, comm) of the global image, i.e. "
                             f"{expected} planes on ranks 0..{size - 1}; got {[s[0] for s in shapes]}")
        local = phases
    else:
        local = phases[i0:i1]
    ids, counts = np.unique(local, return_counts=True)
    all_ids = sorted({int(p) for part in comm.allgather(ids.tolist()) for p in part})
    run = _check_inputs(np.array(all_ids, dtype=np.intp).reshape(-1, 1, 1), materials, **settings)
    totals = np.zeros(len(all_ids), dtype=np.int64)
    for p, c in zip(ids, counts):
        totals[all_ids.index(int(p))] = c
    comm.Allreduce(MPI.IN_PLACE, totals, op=MPI.SUM)
    return dataclasses.replace(run, phases=np.ascontiguousarray(local), shape=shape, i0=i0,
                               counts={p: int(c) for p, c in zip(all_ids, totals)}, comm=comm)


class _Checkpoints:
    """Per checkpoint tolerance and load case, the state a run with ``tol = t`` would stop at.

    ``hits[k][case] = (⟨σ⟩, iterations, seconds since the case started, reached)``.
    """

    def __init__(self, marks: list[float]):
        self.marks = marks
        self.hits: list[list[tuple]] = [[] for _ in marks]

    def record(self, case: int, it: int, res: float, mean: np.ndarray, t0: float) -> None:
        """Called after every iteration: the first state of ``case`` with residual ≤ t is kept."""
        for k, t in enumerate(self.marks):
            if len(self.hits[k]) == case and res <= t:
                self.hits[k].append((mean.copy(), it, time.perf_counter() - t0, True))

    def finish(self, case: int, mean: np.ndarray, iterations: int, t0: float) -> None:
        """A checkpoint the case never reached holds its final state, flagged as not reached."""
        for k in range(len(self.marks)):
            if len(self.hits[k]) == case:
                self.hits[k].append((mean, iterations, time.perf_counter() - t0, False))

    def summary(self, strains: np.ndarray, setup_s: float) -> list[dict]:
        columns = [_stiffness_columns(strains, np.array([h[0] for h in hit])) for hit in self.hits]
        return [{"tol": t, "C": 0.5 * C + 0.5 * C.T, "iterations": [h[1] for h in hit],
                 "wall_s": setup_s + sum(h[2] for h in hit), "converged": all(h[3] for h in hit)}
                for t, C, hit in zip(self.marks, columns, self.hits)]


@dataclass
class _Case:
    """One solved load case."""

    mean: np.ndarray  #: ⟨σ⟩ (Voigt)
    history: list[float]  #: relative residuals, iteration 0 first
    converged: bool
    message: str  #: why it did not converge ("" if it did)
    seconds: float  #: wall time of the solve
    fft_seconds: float  #: of which in the FFTs
    fields: tuple[np.ndarray, np.ndarray] | None  #: (strain, stress), Voigt, if asked for

    @property
    def iterations(self) -> int:
        return len(self.history) - 1


def _solve_case(ws: _Workspace, run: _Run, case: int, E_voigt: np.ndarray, marks: _Checkpoints,
                callback: Callable | None) -> _Case:
    """Solve load case ``case`` (macroscopic Voigt strain ``E_voigt``) with the run's scheme.

    The scheme sees the strain scaled by a power of two (largest component in [1, 2)) and the scaled
    stiffnesses (:func:`_check_materials`), so its norms stay far from overflow and underflow; ⟨σ⟩ and the fields
    are scaled back exactly. A non-finite residual or ⟨σ⟩ raises :class:`ComputationError`.
    """
    k_strain = 1 - _binary_exponent(float(np.abs(E_voigt).max()))
    k_stress = -(k_strain + run.scale)  # solver's ⟨σ⟩ × 2**k_stress = ⟨σ⟩ of the given materials and strain
    E = np.ldexp(E_voigt, k_strain) / _MANDEL
    t0, f0 = time.perf_counter(), ws.fft_s

    def report(it, res, mean):
        if not np.isfinite(res):
            raise ComputationError(f"load case {case} (E = {E_voigt.tolist()}): the residual is {res} at "
                                   f"iteration {it}: the fields overflowed or hold NaN")
        if callback is not None:
            callback(case, it, res)
        with np.errstate(over="ignore"):  # an overflowing ⟨σ⟩ is reported at the end of the case
            marks.record(case, it, res, np.ldexp(mean, k_stress), t0)

    if run.scheme == "cg":
        mean, history, ok, message = _solve_cg(ws, E, run.tol, run.maxiter, report, run.keep_iterate)
    elif run.scheme == "pcg":
        load = _nodal.load_norm(ws, run.stiffness, run.counts, E)
        mean, history, ok, message = _nodal.solve_pcg(ws, E, run.tol, run.maxiter, report, load)
    else:
        mean, history, ok, message = _solve_basic(ws, E, run.tol, run.maxiter, report, run.reference)
    seconds, fft_seconds = time.perf_counter() - t0, ws.fft_s - f0
    with np.errstate(over="ignore"):
        mean = np.ldexp(mean, k_stress)
    if not np.all(np.isfinite(mean)):
        raise ComputationError(f"load case {case} (E = {E_voigt.tolist()}): the mean stress is not finite "
                               f"({mean.tolist()}): it overflows double precision in these units")
    marks.finish(case, mean, len(history) - 1, t0)
    if not ok:
        message = f"load case {case} (E = {E_voigt.tolist()}): {message}; residual {history[-1]:.3g} > {run.tol:g}"
    fields = None
    if run.return_fields:
        strain, stress = _case_fields(ws, run, E)
        fields = (np.ldexp(strain, -k_strain), np.ldexp(stress, k_stress))
    return _Case(mean, history, ok, message, seconds, fft_seconds, fields)


def _case_fields(ws: _Workspace, run: _Run, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Strain and stress fields (Voigt) of the case just solved."""
    if run.scheme == "pcg":
        return ws.strain_stress(E)
    strain = ws.vectors[0]  # basic: ε
    if run.scheme == "cg":  # E + the CG iterate ε̃
        strain = ws.vectors[2]
        strain += E[:, None, None, None]
    ws.constitutive(ws.real, strain)
    return strain * _MANDEL[:, None, None, None], ws.real.copy()


def _assemble_result(run: _Run, cases: list[_Case], stats: dict, checkpoints: list[dict],
                     t_start: float, comm=None) -> HomogenizationResult:
    """C from the load cases' mean stresses, with the settings, timings and checkpoints in ``info``."""
    mean_stress = np.array([c.mean for c in cases])
    iterations = [c.iterations for c in cases]
    failures = [c.message for c in cases if not c.converged]
    iter_s, iter_fft_s = sum(c.seconds for c in cases), sum(c.fft_seconds for c in cases)
    n_iter = max(sum(iterations), 1)
    info = {
        "scheme": run.scheme, "discretization": run.discretization, "shape": list(run.shape),
        "box": list(run.box), "tol": run.tol, "maxiter": run.maxiter, "threads": run.threads,
        "stopping_criterion": "||G[sigma]|| / ||G[C:E]|| <= tol (L2 norms of Mandel fields)",
        "internal_representation": "Mandel",
        "volume_fractions": stats["volume_fractions"],
        "macro_strains": run.strains, "mean_stress": mean_stress,
        "plan_s": stats["plan_s"], "fft_s": stats["fft_s"], "fft_calls": stats["fft_calls"],
        "time_per_iteration_s": iter_s / n_iter, "fft_time_per_iteration_s": iter_fft_s / n_iter,
        "iteration_to_fft_ratio": iter_s / iter_fft_s if iter_fft_s > 0 else None,
        "work_bytes": stats["work_bytes"],
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "failures": failures,
    }
    if checkpoints:
        info["checkpoints"] = checkpoints
    if comm is not None:  # this rank's figures above; every rank's here
        info["ranks"] = comm.Get_size()
        info["planes"] = [run.i0, run.i0 + run.phases.shape[0]]
        info["work_bytes_per_rank"] = comm.allgather(info["work_bytes"])
        info["peak_rss_bytes_per_rank"] = comm.allgather(info["peak_rss_bytes"])
    if run.reference is not None:
        ref = run.reference
        info["reference_medium"] = {"lambda0": float(np.ldexp(ref.lam, -run.scale)),
                                    "mu0": float(np.ldexp(ref.mu, -run.scale)), "contraction_factor": ref.rate}
    fields = None
    if run.return_fields:
        fields = {"strain": np.array([c.fields[0] for c in cases]), "stress": np.array([c.fields[1] for c in cases])}
    C_raw = _stiffness_columns(run.strains, mean_stress)
    solved = np.isin(np.arange(6), [np.flatnonzero(E)[0] for E in run.strains if np.count_nonzero(E) == 1])
    if not np.all(np.isfinite(C_raw[:, solved])):
        raise ComputationError(f"the homogenized stiffness has non-finite entries (⟨σ⟩/E overflows double "
                               f"precision): C = {np.array2string(C_raw, precision=4)}")
    return HomogenizationResult.from_columns(
        C_raw, method="fft", iterations=iterations,
        residuals=[c.history for c in cases], wall_s=time.perf_counter() - t_start, converged=not failures,
        info=info, fields=fields)
