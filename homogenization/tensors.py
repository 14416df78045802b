"""Elasticity tensor utilities: Voigt, Mandel and fourth-order forms, TI and isotropic stiffnesses.

Conventions (docs/conventions.md)
---------------------------------
* Voigt order ``(11, 22, 33, 23, 13, 12)`` with engineering shear strains ``γ_ij = 2 ε_ij``.
  Every 6×6 that crosses a module boundary is a Voigt *stiffness* in this order.
* Mandel: the same order, with ``√2`` on shear components, so that the 6×6 matrix is the
  orthonormal-basis representation of the fourth-order tensor: ``C_M = W C_V W``,
  ``W = diag(1, 1, 1, √2, √2, √2)``. Norms and projections are taken in Mandel form
  (equal to the tensor Frobenius norm).
* Transverse isotropy: local axis 3 is the symmetry (longitudinal, *l*) axis; 1–2 is the plane
  of isotropy. ``E_t = E1 = E2``, ``E_l = E3``, ``nu_t = ν12``, ``nu_tl = ν13 = ν23``,
  ``G_l = G13 = G23``, ``G12 = E_t / (2 (1 + nu_t))``. ``ν_ij`` is the contraction in *j* under
  extension in *i*, so ``ν31 = nu_tl E_l / E_t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from foambase.errors import InputError

__all__ = [
    "VOIGT_PAIRS",
    "InadmissibleMaterialError",
    "IsotropicFit",
    "TransverseIsotropicFit",
    "check_isotropic",
    "check_stiffness",
    "check_transverse_isotropic",
    "closest_isotropic",
    "closest_transverse_isotropic",
    "engineering_constants",
    "isotropic_voigt",
    "mandel_to_voigt",
    "rotate_voigt",
    "rotation_from_axis",
    "tensor_to_voigt",
    "transverse_isotropic_compliance",
    "transverse_isotropic_voigt",
    "voigt_to_mandel",
    "voigt_to_tensor",
]

#: Index pairs (i, j) of the six Voigt components, in the project's order 11, 22, 33, 23, 13, 12.
VOIGT_PAIRS: tuple[tuple[int, int], ...] = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))

_W = np.array([1.0, 1.0, 1.0, np.sqrt(2.0), np.sqrt(2.0), np.sqrt(2.0)])


class InadmissibleMaterialError(InputError):
    """A set of elastic constants or a stiffness matrix violates a thermodynamic admissibility condition."""


# --------------------------------------------------------------------------------------------------
# Representations
# --------------------------------------------------------------------------------------------------
def _as_6x6(C: np.ndarray, name: str = "C") -> np.ndarray:
    try:
        C = np.asarray(C, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a 6×6 matrix of numbers, got {C!r:.80}") from exc
    if C.shape != (6, 6):
        raise InputError(f"{name} must be a 6×6 matrix, got shape {C.shape}")
    return C


def voigt_to_mandel(C: np.ndarray) -> np.ndarray:
    """Voigt stiffness → Mandel stiffness, ``C_M = W C_V W`` with ``W = diag(1,1,1,√2,√2,√2)``."""
    C = _as_6x6(C)
    return C * np.outer(_W, _W)


def mandel_to_voigt(C_M: np.ndarray) -> np.ndarray:
    """Mandel stiffness → Voigt stiffness (inverse of :func:`voigt_to_mandel`)."""
    C_M = _as_6x6(C_M)
    return C_M / np.outer(_W, _W)


def voigt_to_tensor(C: np.ndarray) -> np.ndarray:
    """Voigt stiffness → fourth-order tensor ``C_ijkl`` (3,3,3,3) with minor and major symmetries."""
    C = _as_6x6(C)
    T = np.empty((3, 3, 3, 3))
    for I, (i, j) in enumerate(VOIGT_PAIRS):
        for J, (k, l) in enumerate(VOIGT_PAIRS):
            v = C[I, J]
            T[i, j, k, l] = T[j, i, k, l] = T[i, j, l, k] = T[j, i, l, k] = v
    return T


def tensor_to_voigt(T: np.ndarray) -> np.ndarray:
    """Fourth-order stiffness tensor (3,3,3,3) → Voigt 6×6 (minor-symmetrised)."""
    T = np.asarray(T, dtype=float)
    if T.shape != (3, 3, 3, 3):
        raise InputError(f"expected a (3,3,3,3) tensor, got shape {T.shape}")
    C = np.empty((6, 6))
    for I, (i, j) in enumerate(VOIGT_PAIRS):
        for J, (k, l) in enumerate(VOIGT_PAIRS):
            C[I, J] = 0.25 * (T[i, j, k, l] + T[j, i, k, l] + T[i, j, l, k] + T[j, i, l, k])
    return C


def rotate_voigt(C: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotate a Voigt stiffness: ``C'_ijkl = R_ip R_jq R_kr R_ls C_pqrs``.

    ``R`` maps local (material) axes to global axes: column *k* of ``R`` is the global direction
    of local axis *k*. Rotating a TI stiffness by ``R = rotation_from_axis(a)`` puts its l axis along ``a``.
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        raise InputError(f"R must be 3×3, got shape {R.shape}")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-10) or np.linalg.det(R) < 0:
        raise InputError("R must be a proper rotation matrix (R Rᵀ = I, det R = +1)")
    T = voigt_to_tensor(C)
    return tensor_to_voigt(np.einsum("ip,jq,kr,ls,pqrs->ijkl", R, R, R, R, T, optimize=True))


def rotation_from_axis(a: np.ndarray) -> np.ndarray:
    """A proper rotation whose third column is the unit vector along ``a`` (local 3 → ``a``).

    The in-plane axes are arbitrary, which is harmless for a transversely isotropic tensor.
    """
    a = np.asarray(a, dtype=float).reshape(3)
    n = np.linalg.norm(a)
    if not np.isfinite(n) or n == 0.0:
        raise InputError(f"axis must be a finite non-zero vector, got {a.tolist()}")
    e3 = a / n
    helper = np.eye(3)[np.argmin(np.abs(e3))]
    e1 = np.cross(helper, e3)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e3, e1)
    return np.column_stack([e1, e2, e3])


# --------------------------------------------------------------------------------------------------
# Constructors and admissibility
# --------------------------------------------------------------------------------------------------
def check_isotropic(E: float, nu: float) -> None:
    """Raise :class:`InadmissibleMaterialError` unless ``E > 0`` and ``-1 < nu < 1/2``."""
    if not (np.isfinite(E) and E > 0):
        raise InadmissibleMaterialError(f"Young's modulus must be > 0, got E = {E}")
    if not (np.isfinite(nu) and -1.0 < nu < 0.5):
        raise InadmissibleMaterialError(f"Poisson's ratio must satisfy -1 < nu < 0.5, got nu = {nu}")


def check_transverse_isotropic(E_t: float, E_l: float, nu_t: float, nu_tl: float, G_l: float) -> None:
    """Raise :class:`InadmissibleMaterialError` unless the TI compliance is positive definite.

    The conditions (positive definiteness of the compliance in docs/conventions.md) are
    ``E_t > 0``, ``E_l > 0``, ``G_l > 0``, ``-1 < nu_t < 1`` and
    ``1 - nu_t - 2 nu_tl² E_l / E_t > 0``.
    """
    for name, value in (("E_t", E_t), ("E_l", E_l), ("G_l", G_l)):
        if not (np.isfinite(value) and value > 0):
            raise InadmissibleMaterialError(f"{name} must be > 0, got {name} = {value}")
    if not (np.isfinite(nu_t) and -1.0 < nu_t < 1.0):
        raise InadmissibleMaterialError(f"nu_t must satisfy -1 < nu_t < 1, got nu_t = {nu_t}")
    if not np.isfinite(nu_tl):
        raise InadmissibleMaterialError(f"nu_tl must be finite, got nu_tl = {nu_tl}")
    bound = np.sqrt((1.0 - nu_t) * E_t / (2.0 * E_l))  # |nu_tl| < bound, without squaring a huge nu_tl
    margin = 1.0 - nu_t - 2.0 * float(nu_tl) ** 2 * E_l / E_t if abs(nu_tl) < 2.0 * bound else -np.inf
    if margin <= 0:
        raise InadmissibleMaterialError(
            "transverse isotropy requires 1 - nu_t - 2 nu_tl² E_l/E_t > 0, got "
            f"{margin:.4g} (nu_t = {nu_t}, nu_tl = {nu_tl}, E_l/E_t = {E_l / E_t:.4g}: |nu_tl| < {bound:.4g})"
        )


def check_stiffness(C: np.ndarray, *, allow_zero: bool = False, rtol: float = 1e-8, name: str = "C") -> None:
    """Raise :class:`InadmissibleMaterialError` unless ``C`` is symmetric positive definite.

    ``allow_zero`` accepts the exactly-zero matrix (a void phase). Symmetry is checked relative to
    ``max|C|``; positive definiteness on the Mandel form (smallest eigenvalue > ``rtol·max eig``).
    """
    C = _as_6x6(C, name)
    if not np.all(np.isfinite(C)):
        raise InadmissibleMaterialError(f"{name} has non-finite entries")
    scale = np.abs(C).max()
    if scale == 0.0:
        if allow_zero:
            return
        raise InadmissibleMaterialError(f"{name} is zero; a zero stiffness is only valid for a void phase")
    asym = np.abs(C - C.T).max() / scale
    if asym > rtol:
        raise InadmissibleMaterialError(f"{name} is not symmetric: max|C - Cᵀ|/max|C| = {asym:.3g} > {rtol:g}")
    eig = np.linalg.eigvalsh(voigt_to_mandel(0.5 * (C + C.T)))
    if eig[0] <= rtol * eig[-1]:
        raise InadmissibleMaterialError(
            f"{name} is not positive definite: smallest Mandel eigenvalue {eig[0]:.4g} (largest {eig[-1]:.4g})"
        )


def isotropic_voigt(E: float, nu: float) -> np.ndarray:
    """Isotropic Voigt stiffness: ``λ = E ν / ((1+ν)(1-2ν))``, ``μ = E / (2(1+ν))``; ``C = λ 1⊗1 + 2μ I``."""
    check_isotropic(E, nu)
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[np.arange(3), np.arange(3)] += 2 * mu
    C[np.arange(3, 6), np.arange(3, 6)] = mu
    return C


def transverse_isotropic_compliance(E_t: float, E_l: float, nu_t: float, nu_tl: float, G_l: float) -> np.ndarray:
    """TI Voigt compliance in the local frame (l = axis 3), the closed form of docs/conventions.md.

    ``S11 = S22 = 1/E_t``, ``S33 = 1/E_l``, ``S12 = -nu_t/E_t``, ``S13 = S23 = -nu_tl/E_t``,
    ``S44 = S55 = 1/G_l``, ``S66 = 2(1 + nu_t)/E_t``. Numbers give one (6, 6) compliance, checked for
    admissibility; arrays (one value per cell) give (m, 6, 6), unchecked (the per-cell moduli of graded foams).
    """
    constants = (E_t, E_l, nu_t, nu_tl, G_l)
    if all(np.ndim(c) == 0 for c in constants):
        check_transverse_isotropic(*constants)
    S = np.zeros((6, 6, *np.broadcast(*constants).shape))  # per-cell values along the trailing axes
    S[0, 0] = S[1, 1] = 1.0 / E_t
    S[2, 2] = 1.0 / E_l
    S[0, 1] = S[1, 0] = -nu_t / E_t
    S[0, 2] = S[2, 0] = S[1, 2] = S[2, 1] = -nu_tl / E_t
    S[3, 3] = S[4, 4] = 1.0 / G_l
    S[5, 5] = 2.0 * (1.0 + nu_t) / E_t
    return np.moveaxis(S, (0, 1), (-2, -1))


def transverse_isotropic_voigt(E_t: float, E_l: float, nu_t: float, nu_tl: float, G_l: float) -> np.ndarray:
    """TI Voigt stiffness in the local frame (l = axis 3): the inverse of the closed-form compliance."""
    C = np.linalg.inv(transverse_isotropic_compliance(E_t, E_l, nu_t, nu_tl, G_l))
    return 0.5 * (C + C.T)


# --------------------------------------------------------------------------------------------------
# Engineering constants and fits
# --------------------------------------------------------------------------------------------------
def engineering_constants(C: np.ndarray) -> dict[str, float]:
    """Engineering constants of a Voigt stiffness, from the compliance ``S = C⁻¹``.

    ``E_i = 1/S_ii``; ``G23 = 1/S44``, ``G13 = 1/S55``, ``G12 = 1/S66``;
    ``ν_ij = -S_ij / S_ii`` (contraction in *j* under extension in *i*).
    """
    check_stiffness(C)
    S = np.linalg.inv(_as_6x6(C))
    out = {"E1": 1 / S[0, 0], "E2": 1 / S[1, 1], "E3": 1 / S[2, 2],
           "G23": 1 / S[3, 3], "G13": 1 / S[4, 4], "G12": 1 / S[5, 5]}
    for i in range(3):
        for j in range(3):
            if i != j:
                out[f"nu{i + 1}{j + 1}"] = -S[i, j] / S[i, i]
    return {k: float(v) for k, v in out.items()}


def _ti_basis() -> np.ndarray:
    """Orthonormal (Frobenius) basis of the 5-dim space of TI Mandel stiffnesses with axis 3."""
    def E(*pairs):
        M = np.zeros((6, 6))
        for i, j in pairs:
            M[i, j] = M[j, i] = 1.0
        return M
    # C11 = C22 and C66_M = C11 - C12 (Mandel), C12, C13 = C23, C33, C44 = C55.
    raw = [E((0, 0), (1, 1), (5, 5)), E((0, 1)) - E((5, 5)), E((0, 2), (1, 2)), E((2, 2)), E((3, 3), (4, 4))]
    Q, _ = np.linalg.qr(np.array([m.ravel() for m in raw]).T)
    return Q.T.reshape(5, 6, 6)


_TI_BASIS = _ti_basis()
_J = np.zeros((6, 6))
_J[:3, :3] = 1.0 / 3.0  # J = (1/3) 1⊗1 in Mandel; K = I - J.


@dataclass(frozen=True)
class IsotropicFit:
    """Closest isotropic stiffness to a given C (Mandel/Frobenius least squares)."""

    E: float
    nu: float
    C: np.ndarray  #: the isotropic Voigt stiffness
    error: float   #: ‖C - C_iso‖ / ‖C‖ in Mandel norm


@dataclass(frozen=True)
class TransverseIsotropicFit:
    """Closest transversely isotropic stiffness with l axis ``axis`` (global) to a given C."""

    E_t: float
    E_l: float
    nu_t: float
    nu_tl: float
    G_l: float
    axis: tuple[float, float, float]  #: l axis in the global frame
    C: np.ndarray  #: the TI stiffness, global Voigt
    error: float   #: ‖C - C_TI‖ / ‖C‖ in Mandel norm

    @property
    def constants(self) -> dict[str, float]:
        """The five TI constants as a dict (keys as the :class:`TransverseIsotropic` fields)."""
        return {"E_t": self.E_t, "E_l": self.E_l, "nu_t": self.nu_t, "nu_tl": self.nu_tl, "G_l": self.G_l}


def closest_isotropic(C: np.ndarray) -> IsotropicFit:
    """Orthogonal projection of ``C`` onto isotropic tensors, with the relative error of the fit.

    ``C_iso = 3κ J + 2μ K`` with ``3κ = J::C`` and ``2μ = K::C / 5`` (Mandel double contraction).
    """
    C = _as_6x6(C)
    M = voigt_to_mandel(0.5 * (C + C.T))
    K = np.eye(6) - _J
    three_kappa = np.sum(_J * M)
    two_mu = np.sum(K * M) / 5.0
    M_iso = three_kappa * _J + two_mu * K
    kappa, mu = three_kappa / 3.0, two_mu / 2.0
    E = 9 * kappa * mu / (3 * kappa + mu)
    nu = (3 * kappa - 2 * mu) / (2 * (3 * kappa + mu))
    err = np.linalg.norm(M - M_iso) / np.linalg.norm(M)
    return IsotropicFit(E=float(E), nu=float(nu), C=mandel_to_voigt(M_iso), error=float(err))


def closest_transverse_isotropic(C: np.ndarray, axis=(0.0, 0.0, 1.0)) -> TransverseIsotropicFit:
    """Orthogonal projection of ``C`` onto TI tensors whose l axis is ``axis``, with the fit error.

    ``axis`` is a global vector or 0/1/2 for x/y/z. ``C`` is rotated
    into the frame where l = local 3, projected onto the
    5-dimensional TI subspace (Mandel/Frobenius least squares), and the five constants are read
    from the compliance of the projection. The fit error is ``‖C - C_TI‖/‖C‖`` (Mandel norm).
    """
    C = _as_6x6(C)
    if np.isscalar(axis) or np.ndim(axis) == 0:
        if int(axis) not in (0, 1, 2):
            raise InputError(f"axis must be 0, 1, 2 or a 3-vector, got {axis}")
        axis = np.eye(3)[int(axis)]
    R = rotation_from_axis(axis)
    C_loc = rotate_voigt(0.5 * (C + C.T), R.T)
    M = voigt_to_mandel(C_loc)
    M_ti = np.einsum("kij,k->ij", _TI_BASIS, np.einsum("kij,ij->k", _TI_BASIS, M))
    C_ti_loc = mandel_to_voigt(M_ti)
    err = np.linalg.norm(M - M_ti) / np.linalg.norm(M)
    S = np.linalg.inv(C_ti_loc)
    a = np.asarray(axis, dtype=float)
    return TransverseIsotropicFit(
        E_t=float(1 / S[0, 0]), E_l=float(1 / S[2, 2]), nu_t=float(-S[0, 1] / S[0, 0]),
        nu_tl=float(-S[0, 2] / S[0, 0]), G_l=float(1 / S[3, 3]),
        axis=tuple(float(x) for x in a / np.linalg.norm(a)),
        C=rotate_voigt(C_ti_loc, R), error=float(err),
    )
