"""The mixed contact problem condensed onto its face unknowns (``mixed`` only).

In the ``mixed`` formulation only the multiplier equations are nonlinear: the displacement
equation ``K u + Bᵀλ = f(p)`` and the face averages ``a = π⁰[[u]]`` (relative to the slip
reference) are linear, and the multiplier equations ``λ + [P(λ, a)]`` involve ``λ`` and ``a``
only, face by face. Replacing the multiplier rows of the Jacobian by the face mass matrix gives
a constant matrix ``J₀`` (the elastic operator plus the linear rows); one MUMPS factorization of
``J₀`` for the run, and the Schur complement of ``J₀`` on the face unknowns ``(λ, a)``
(computed by MUMPS in the same kind of factorization, once), give the exact affine map
``a(λ) = a₁ + G (λ - λ₀)`` with ``G = -S_aa⁻¹ S_aλ`` (dense, ``n_λ × n_λ``). A contact solve is
then

1. one back-substitution with ``J₀``: the displacement and averages at the current ``λ₀``;
2. a semi-smooth Newton on the ``n_λ`` face equations ``R(λ) = |σ|(λ + [P(λ, a(λ))])``, dense
   and small (1,440 unknowns on the finest mesh of the six-fracture scene), with the same
   branches and tie conventions as the UFL forms (:mod:`poromech.forms.contact`) and a line
   search whose trial residuals cost a dense matrix-vector product, not an assembly;
3. a second back-substitution: the displacement for the final ``λ``.

The result is a candidate that the regular Newton
(:class:`~poromech.mechanics.newton.SemiSmoothNewton`)
then checks with an assembled residual: it stops at iteration 0 when the candidate meets its
tolerance, and otherwise iterates from it as usual, so the condensed solve changes the cost of a
solve, never its answer or its convergence test. The face problem runs on rank 0 (MUMPS returns
the Schur complement there) and its result is scattered back.

Used for ``mixed`` with displacements of degree >= 2 (with P1 the face problem is singular when
every face sticks), with the default direct solver, Young's modulus and Poisson's ratio
constant in time, and at most :data:`MAX_FACE_UNKNOWNS` face unknowns (the dense Schur
complement has ``(2 n_λ)²`` entries). If the factorization of ``J₀`` fails (e.g. a fracture
network that cuts a block free, held only by contact, makes the elastic operator singular), the
condensation is switched off and every solve is the regular Newton.
"""

from __future__ import annotations

import ctypes
import glob
import logging
import os
import time
from dataclasses import dataclass

import dolfinx_solver  # noqa: F401

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from dolfinx.fem.petsc import assemble_matrix, assign, create_matrix
from petsc4py import PETSc

from poromech.petsc_options import PrefixedOptions

__all__ = ["CondensedContact", "MAX_FACE_UNKNOWNS", "applicable"]

log = logging.getLogger("poromech")

#: Options prefix of the factorizations of the condensation matrix (MUMPS options of the
#: scene's ``solver.petsc`` are applied to them too).
PREFIX = "mech_condensed_"
#: Largest number of face unknowns (multiplier components) condensed: the Schur complement on
#: ``(λ, a)`` is a dense matrix of ``(2 n_λ)²`` entries on rank 0 (8,000 → 0.5 GB).
MAX_FACE_UNKNOWNS = 8_000
#: Iterations of the face Newton before it gives up (each costs a dense solve of ``n_λ``).
MAX_IT = 200
#: Consecutive steps without decrease of the face residual before the face Newton gives up.
MAX_WATCHDOG = 5
#: Fraction of the regular Newton's tolerance that the face residual must reach: the linear
#: rows after two back-substitutions carry round-off, the face rows then carry none of it.
SAFETY = 1e-2


def applicable(formulation: str, degree: int, friction: str) -> bool:
    """Whether the scene's contact problem can be condensed (see the module docstring)."""
    return formulation == "mixed" and degree >= 2 and friction in (
        "coulomb", "tresca", "frictionless")


def _petsc_library() -> ctypes.CDLL:
    """The PETSc shared library loaded by petsc4py (for the calls petsc4py does not expose)."""
    with open("/proc/self/maps") as f:
        paths = {line.split()[-1] for line in f if "libpetsc.so" in line}
    paths |= set(glob.glob(os.path.join(os.path.dirname(dolfinx_solver.__file__), "lib",
                                        "libpetsc.so*")))
    if not paths:
        raise RuntimeError("the PETSc library is not found")
    return ctypes.CDLL(sorted(paths)[0])


def _direct_solver(A: PETSc.Mat) -> PETSc.KSP:
    """A MUMPS LU of ``A`` (options prefix :data:`PREFIX`), not yet set up."""
    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOptionsPrefix(PREFIX)
    ksp.setOperators(A)
    ksp.setType("preonly")
    pc = ksp.getPC()
    pc.setType("lu")
    pc.setFactorSolverType("mumps")
    return ksp


def _schur_complement(A: PETSc.Mat, rows: npt.NDArray,
                      options: PrefixedOptions) -> npt.NDArray | None:
    """Dense Schur complement of ``A`` on the global ``rows`` (sorted), on rank 0 (collective).

    MUMPS computes it during a factorization (ICNTL(19), centralized on the host); the factor
    is discarded. Returns the matrix on rank 0 and None elsewhere.
    """
    lib = _petsc_library()
    comm = A.getComm()
    ksp = _direct_solver(A)
    try:
        pc = ksp.getPC()
        pc.setFactorSetUpSolverType()
        F = pc.getFactorMatrix()
        iset = PETSc.IS().createGeneral(rows.astype(PETSc.IntType), comm=comm)
        err = lib.MatFactorSetSchurIS(ctypes.c_void_p(F.handle), ctypes.c_void_p(iset.handle))
        if err:
            raise RuntimeError(f"MatFactorSetSchurIS failed ({err})")
        with options:
            pc.setUp()
        S = ctypes.c_void_p()
        status = ctypes.c_int()
        err = lib.MatFactorCreateSchurComplement(ctypes.c_void_p(F.handle), ctypes.byref(S),
                                                 ctypes.byref(status))
        if err:
            raise RuntimeError(f"MatFactorCreateSchurComplement failed ({err})")
        try:
            n = len(rows)
            if comm.rank != 0 or n == 0:
                return None
            ptr = ctypes.POINTER(ctypes.c_double)()
            lib.MatDenseGetArrayRead(S, ctypes.byref(ptr))
            dense = np.ctypeslib.as_array(ptr, shape=(n, n)).T.copy()  # column-major
            lib.MatDenseRestoreArrayRead(S, ctypes.byref(ptr))
            return dense
        finally:
            lib.MatDestroy(ctypes.byref(S))
            iset.destroy()
    finally:
        ksp.destroy()


@dataclass
class FaceProblem:
    """The face equations of ``mixed`` on rank 0, in the order of the Schur complement.

    Attributes:
        length: ``|σ|`` per face (m).
        beta_n, beta_t: ``β^sm/|σ|`` per face (Pa/m).
        ln, lt: Positions of ``λ_n``, ``λ_τ`` of each face among the multiplier unknowns.
        an, at: Rows of ``G`` (positions among the averages) of ``a_n``, ``a_τ``.
        G: ``∂a/∂λ`` (averages × multipliers).
        friction: ``coulomb``, ``tresca`` or ``frictionless``.
    """

    length: npt.NDArray[np.float64]
    beta_n: npt.NDArray[np.float64]
    beta_t: npt.NDArray[np.float64]
    ln: npt.NDArray[np.int64]
    lt: npt.NDArray[np.int64] | None
    an: npt.NDArray[np.int64]
    at: npt.NDArray[np.int64] | None
    G: npt.NDArray[np.float64]
    friction: str

    def residual(self, lam: npt.NDArray, a: npt.NDArray, coefficient: float, bound: float,
                 jacobian: bool = False):
        """``R = |σ|(λ + [P])`` and, with ``jacobian``, ``dR/dλ`` through ``a(λ)``.

        Branches and ties are those of :mod:`poromech.forms.fracture` (``[x]_R-`` takes the
        contact branch at 0, ``[x]_S`` the stick branch on ``|x| = S``).
        """
        L, ln, an = self.length, self.ln, self.an
        R = np.empty_like(lam)
        pn = -(lam[ln] + self.beta_n * a[an])
        contact = pn <= 0.0
        R[ln] = L * (lam[ln] + np.where(contact, pn, 0.0))
        J = None
        if jacobian:
            n = lam.size
            J = np.zeros((n, n))
            rows_c = ln[contact]
            J[rows_c] = -(L * self.beta_n)[contact, None] * self.G[an[contact]]
            J[ln[~contact], ln[~contact]] = L[~contact]
        if self.lt is None:
            return R, J
        lt, at = self.lt, self.at
        pt = -(lam[lt] + self.beta_t * a[at])
        if self.friction == "coulomb":
            S = -coefficient * np.where(contact, pn, 0.0)
        else:
            S = np.full_like(pt, bound)
        stick = (pt <= S) & (pt >= -S)
        above = pt > S
        sign = np.where(above, 1.0, -1.0)
        proj = np.where(stick, pt, sign * S)
        R[lt] = L * (lam[lt] + proj)
        if jacobian:
            J[lt[stick]] = -(L * self.beta_t)[stick, None] * self.G[at[stick]]
            slip = ~stick
            J[lt[slip], lt[slip]] = L[slip]
            if self.friction == "coulomb":
                moving = slip & contact  # dS/dλ = F (e_n + β_n G_n) on the contact branch
                rows = lt[moving]
                w = (sign * L * coefficient)[moving]
                J[rows] += w[:, None] * (self.beta_n[moving, None] * self.G[an[moving]])
                J[rows, ln[moving]] += w
        return R, J


class _RowUpdatedInverse:
    """Solves with dense matrices that differ from a factorized one in a few rows (rank 0).

    The face Jacobian is a function of the branches only (``G``, ``|σ|``, ``β`` and ``F`` are
    constant), and from one face Newton iteration, ``g`` evaluation or time step to the next
    only the rows of the faces that switched change. The inverse of a base matrix is kept and a
    matrix with ``k`` changed rows is solved by the Woodbury formula (``O(n k² + n²)`` instead
    of ``O(n³)``); the base is replaced when more than :attr:`max_rows` rows changed.
    """

    def __init__(self, n: int):
        self.base: npt.NDArray | None = None
        self.inverse: npt.NDArray | None = None
        #: What the base is the Jacobian of (the caller's data, kept with it for a checkpoint).
        self.origin = None
        self.max_rows = max(32, n // 5)
        self.inversions = 0

    def solve(self, J: npt.NDArray, r: npt.NDArray, origin=None) -> npt.NDArray:
        """``J⁻¹ r`` (raises ``numpy.linalg.LinAlgError`` when ``J`` is singular).

        ``origin()`` (what ``J`` is the Jacobian of) becomes :attr:`origin` when ``J`` becomes
        the base.
        """
        if self.base is not None:
            changed = np.flatnonzero(np.any(J != self.base, axis=1))
            y = self.inverse @ r
            if changed.size == 0:
                return y
            if changed.size <= self.max_rows:
                V = J[changed] - self.base[changed]
                Z = self.inverse[:, changed]
                try:
                    w = np.linalg.solve(np.eye(changed.size) + V @ Z, V @ y)
                    return y - Z @ w
                except np.linalg.LinAlgError:
                    pass
        self.inverse = np.linalg.inv(J)
        self.base = J.copy()
        self.origin = origin() if origin is not None else None
        self.inversions += 1
        return self.inverse @ r


class CondensedContact:
    """Condensed solves of a ``mixed`` contact problem (collective).

    Args:
        model: The :class:`~poromech.mechanics.model.MechanicsModel` (``mixed``).
        solver: Its :class:`~poromech.mechanics.newton.SemiSmoothNewton` (vectors, residual,
            options).

    Raises:
        RuntimeError: When ``J₀`` cannot be factorized (the caller then solves without).
    """

    def __init__(self, model, solver):
        self.model, self.solver = model, solver
        self.comm = model.fm.comm
        t0 = time.perf_counter()
        self.J0 = create_matrix(model.condensation_jacobian())
        assemble_matrix(self.J0, model.condensation_jacobian(), model.bcs, diag=1.0)
        self.J0.assemble()
        self._layout()
        # the scene's MUMPS options (solver.petsc: mat_mumps_*) apply to both factorizations;
        # null-pivot detection tells a singular elastic operator
        mumps = {k: v for k, v in solver.petsc_options.items() if k.startswith("mat_mumps_")}
        self.options = PrefixedOptions(PREFIX, {**mumps, "mat_mumps_icntl_24": 1})
        self.ksp = _direct_solver(self.J0)
        with self.options:
            self.ksp.setUp()
        F = self.ksp.getPC().getFactorMatrix()
        if self.ksp.getPC().getFailedReason() or F.getMumpsInfog(28) > 0:
            null = F.getMumpsInfog(28)
            self.destroy()
            raise RuntimeError(f"the elastic operator is singular ({null} null pivots: a block "
                               "held only by contact?)" if null else
                               "the factorization of the condensation matrix failed")
        self.problem = self._face_problem()
        self._inverse = _RowUpdatedInverse(self.multipliers) if self.comm.rank == 0 else None
        self._y = self.J0.createVecRight()
        self._rhs = self.J0.createVecLeft()
        self._start = self.J0.createVecRight()  # the unknowns a failed face Newton restores
        self._keep = self.mask_lambda.duplicate()  # 1 on the rows that are not λ's
        self._keep.set(1.0)
        self._keep.axpy(-1.0, self.mask_lambda)
        self._lambda_diagonal = self.J0.getDiagonal()  # |σ| on λ's rows, 0 elsewhere
        self._lambda_diagonal.pointwiseMult(self._lambda_diagonal, self.mask_lambda)
        self.setup_seconds = time.perf_counter() - t0
        self.factorizations = 2

    # -- set-up -----------------------------------------------------------------------------
    def _layout(self) -> None:
        """Rows of ``λ`` and ``a`` in the block vector; a scatter of them to rank 0."""
        m, x = self.model, self.solver.x
        kinds, faces = [], []
        for k, f in enumerate(m.unknowns):
            V = f.function_space
            bs, imap = V.dofmap.index_map_bs, V.dofmap.index_map
            kind = fem.Function(V)
            face = fem.Function(V)
            n = imap.size_local + imap.num_ghosts
            comp = np.tile(np.arange(bs), n)
            kind.x.array[:] = 0 if k == 0 else (10 * k + comp)
            face.x.array[:] = 0 if k == 0 else np.repeat(
                imap.local_to_global(np.arange(n, dtype=np.int32)), bs)
            kinds.append(kind)
            faces.append(face)
        v = x.duplicate()
        assign(kinds, v)
        code = v.getArray().astype(np.int64).copy()
        assign(faces, v)
        face = v.getArray().astype(np.int64).copy()
        v.destroy()
        r0 = x.getOwnershipRange()[0]
        rows = np.flatnonzero(code > 0)
        self.mask_lambda = x.duplicate()
        self.mask_lambda.getArray()[:] = (code // 10 == 1).astype(float)
        gathered = self.comm.gather((rows + r0, code[rows], face[rows]), root=0)
        if self.comm.rank == 0:
            glob_rows = np.concatenate([g[0] for g in gathered])
            self.codes = np.concatenate([g[1] for g in gathered])
            self.faces = np.concatenate([g[2] for g in gathered])
        else:
            glob_rows = np.empty(0, np.int64)
        self.rows = glob_rows
        #: Multiplier unknowns (the size of the face problem).
        self.multipliers = self.comm.bcast(
            int(np.count_nonzero(self.codes // 10 == 1)) if self.comm.rank == 0 else 0, root=0)
        iset = PETSc.IS().createGeneral(glob_rows.astype(PETSc.IntType), comm=PETSc.COMM_SELF)
        self._seq = PETSc.Vec().createSeq(len(glob_rows), comm=PETSc.COMM_SELF)
        self.scatter = PETSc.Scatter().create(x, iset, self._seq, None)
        iset.destroy()

    def _face_problem(self) -> FaceProblem | None:
        """Per-face data and ``G = -S_aa⁻¹ S_aλ`` on rank 0 (collective)."""
        m = self.model
        diag = self.J0.getDiagonal()
        self.scatter.scatter(diag, self._seq, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
        d = self._seq.getArray().copy()
        diag.destroy()
        S = _schur_complement(self.J0, self.rows, self.options)
        if self.comm.rank != 0:
            return None
        codes, faces = self.codes, self.faces
        lam = np.flatnonzero(codes // 10 == 1)
        avg = np.flatnonzero(codes // 10 == 2)
        self.lam_pos, self.avg_pos = lam, avg
        Sal = S[np.ix_(avg, lam)]
        Saa = S[np.ix_(avg, avg)]
        G = -np.linalg.solve(Saa, Sal)
        # faces in the order of λ_n; positions of each component among λ (resp. a)
        lam_codes, lam_faces = codes[lam], faces[lam]
        avg_codes, avg_faces = codes[avg], faces[avg]
        ln = np.flatnonzero(lam_codes == 10)
        order = lam_faces[ln]
        def positions(c, f, comp):
            idx = np.flatnonzero(c == comp)
            lookup = dict(zip(f[idx].tolist(), idx.tolist(), strict=True))
            return np.array([lookup[k] for k in order.tolist()], dtype=np.int64)
        tangential = m.params.tangential
        length = d[lam][ln]  # the face mass matrix: |σ| on the diagonal
        bn0, bt0 = m.beta_sm0
        return FaceProblem(
            length=length, beta_n=bn0 / length, beta_t=bt0 / length,
            ln=ln, lt=positions(lam_codes, lam_faces, 11) if tangential else None,
            an=positions(avg_codes, avg_faces, 20),
            at=positions(avg_codes, avg_faces, 21) if tangential else None,
            G=G, friction=m.scene.contact.friction)

    # -- solves -----------------------------------------------------------------------------
    def gather(self, v: PETSc.Vec) -> npt.NDArray | None:
        """The face rows (``λ`` and ``a``) of a block vector, on rank 0 (collective).

        Positions :attr:`lam_pos` and :attr:`avg_pos` select the multipliers and averages.
        """
        self.scatter.scatter(v, self._seq, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
        return self._seq.getArray().copy() if self.comm.rank == 0 else None

    def scatter_faces(self, values: npt.NDArray | None, v: PETSc.Vec) -> None:
        """Set the face rows of block vector ``v`` from ``values`` given on rank 0 (collective)."""
        if self.comm.rank == 0:
            self._seq.getArray()[:] = values
        self.scatter.scatter(self._seq, v, PETSc.InsertMode.INSERT, PETSc.ScatterMode.REVERSE)

    def law(self) -> tuple[float, float]:
        """The friction coefficient and the Tresca bound of the contact law (0 when unused)."""
        c = self.model.params
        coefficient = float(c.friction_coefficient.value) if c.friction_coefficient is not None \
            else 0.0
        bound = float(c.slip_bound.value) if c.slip_bound is not None else 0.0
        return coefficient, bound

    def solve(self, x: PETSc.Vec, f0: PETSc.Vec, tol: float, min_steps: int) -> dict:
        """The candidate solution, written into ``x`` when the face Newton converged (collective).

        Args:
            x: The current unknowns (block vector); left unchanged when the face Newton fails.
            f0: The assembled residual at ``x``.
            tol: The regular Newton's absolute tolerance; the face residual is solved to
                :data:`SAFETY` times it, or accepted within it when it stagnates at round-off.
            min_steps: Face Newton steps taken even when the tolerance is met at once.

        Returns:
            ``converged``, ``iterations``, ``residuals`` (face residual norms).
        """
        y, start = self._y, self._start
        x.copy(start)
        f0.copy(self._rhs)
        self._rhs.pointwiseMult(self._rhs, self._keep)  # no change of λ
        self.ksp.solve(self._rhs, y)
        x.axpy(-1.0, y)  # the linear rows hold at the current λ
        values = self.gather(x)
        out, step = None, None
        if self.comm.rank == 0:
            out = self._face_newton(values, tol, min_steps)
            step = out.pop("step")
        out = self.comm.bcast(out, root=0)
        if not out["converged"]:
            start.copy(x)
            return out
        x.axpy(1.0, self._response(step, y))
        return out

    def _response(self, step: npt.NDArray | None, y: PETSc.Vec) -> PETSc.Vec:
        """The change of the unknowns for a change ``step`` of ``λ``: ``J₀ y = (0, |σ| δλ, 0)``."""
        v = self._step_vector(step)
        v.pointwiseMult(v, self._lambda_diagonal)
        self.ksp.solve(v, y)
        return y

    def response(self, step: npt.NDArray | None) -> npt.NDArray | None:
        """The face rows of the response to a change ``step`` of ``λ`` (given on rank 0).

        Collective; returned on rank 0. The averages' rows are ``G step`` (the exact affine map
        the face Newton uses), the multipliers' rows ``step``.
        """
        y = self._y.duplicate()
        out = self.gather(self._response(step, y))
        y.destroy()
        return out

    def _step_vector(self, step: npt.NDArray | None) -> PETSc.Vec:
        """Block vector with ``δλ`` in the multiplier rows, zero elsewhere (collective)."""
        v = self._rhs
        v.set(0.0)
        if self.comm.rank == 0:
            self._seq.getArray()[:] = 0.0
            self._seq.getArray()[self.lam_pos] = step
        self.scatter.scatter(self._seq, v, PETSc.InsertMode.INSERT, PETSc.ScatterMode.REVERSE)
        return v

    def _face_newton(self, values: npt.NDArray, tol: float, min_steps: int) -> dict:
        """Semi-smooth Newton on the face equations (rank 0); ``step`` is ``δλ``."""
        p = self.problem
        lam0, a1 = values[self.lam_pos], values[self.avg_pos]
        coefficient, bound = self.law()
        dl = np.zeros_like(lam0)

        def unknowns(d):
            return lam0 + d, a1 + p.G @ d

        def residual(d, jacobian=False):
            return p.residual(*unknowns(d), coefficient, bound, jacobian)

        R, J = residual(dl, True)
        norms = [float(np.linalg.norm(R))]
        watchdog = 0
        for it in range(MAX_IT + 1):
            if norms[-1] <= SAFETY * tol and it >= min_steps:
                return {"converged": True, "iterations": it, "residuals": norms, "step": dl}
            if it == MAX_IT or watchdog >= MAX_WATCHDOG or not np.isfinite(norms[-1]):
                break
            try:
                Y = self._inverse.solve(J, R, lambda d=dl: (*unknowns(d), coefficient, bound))
            except np.linalg.LinAlgError:
                break
            best, best_norm = 1.0, float(np.linalg.norm(residual(dl - Y)[0]))
            if best_norm > (1.0 - 1e-4) * norms[-1]:
                for j in range(1, 7):
                    alpha = 0.5 ** j
                    r = float(np.linalg.norm(residual(dl - alpha * Y)[0]))
                    if r < best_norm:
                        best, best_norm = alpha, r
            watchdog = watchdog + 1 if best_norm >= norms[-1] else 0
            dl = dl - best * Y
            R, J = residual(dl, True)
            norms.append(float(np.linalg.norm(R)))
        # stagnated at its round-off but within the regular tolerance (very large β^sm): the
        # regular Newton checks the result like any other
        usable = bool(norms[-1] <= tol)
        return {"converged": usable, "iterations": len(norms) - 1, "residuals": norms,
                "step": dl if usable else None}

    # -- checkpoint -------------------------------------------------------------------------
    def base_unknowns(self, v: PETSc.Vec) -> tuple[float, float] | None:
        """Write where the kept face inverse's base Jacobian was taken into ``v`` (collective).

        The face rows (``λ`` and ``a``) of block vector ``v`` are set to the unknowns of that
        Jacobian; returns the friction coefficient and Tresca bound it was taken with, or None
        (``v`` untouched) before the first inversion. A restart rebuilds the same base from them
        (:meth:`set_base`), so that its Woodbury solves repeat the uninterrupted run's bit for bit.
        """
        origin = self._inverse.origin if self.comm.rank == 0 else None
        law = self.comm.bcast(None if origin is None else (origin[2], origin[3]), root=0)
        if law is None:
            return None
        values = None
        if self.comm.rank == 0:
            values = np.zeros(self._seq.getSize())
            values[self.lam_pos], values[self.avg_pos] = origin[0], origin[1]
        self.scatter_faces(values, v)
        return law

    def set_base(self, v: PETSc.Vec, law: tuple[float, float]) -> None:
        """Invert the face Jacobian at the face rows of ``v`` as the kept base (collective)."""
        values = self.gather(v)
        if self.comm.rank != 0:
            return
        lam, a = values[self.lam_pos], values[self.avg_pos]
        J = self.problem.residual(lam, a, *law, jacobian=True)[1]
        inverse = self._inverse
        inverse.base, inverse.inverse = None, None
        inverse.solve(J, np.zeros(lam.size), lambda: (lam, a, *law))

    def describe(self) -> dict:
        """Size and work of the condensation, for the summary.

        Not collective: the dense inversions of the face Newton are counted on rank 0, which
        writes the summary.
        """
        inversions = self._inverse.inversions if self._inverse is not None else 0
        return {"multipliers": self.multipliers, "factorizations": self.factorizations,
                "setup_seconds": self.setup_seconds, "dense_inversions": inversions}

    def destroy(self) -> None:
        """Free the PETSc objects (collective)."""
        for name in ("J0", "ksp", "_y", "_rhs", "_start", "_seq", "scatter", "mask_lambda",
                     "_keep", "_lambda_diagonal"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.destroy()
