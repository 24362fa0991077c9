"""Linear solves of the time loop: one step without contact, and the PETSc KSP set-up.

:class:`LinearStepSolver` -- no Gamma_C: J_n is quadratic, each step is one linear solve
with A_const, factored (or preconditioned) once for the whole run; an iterative KSP that
stops above the step tolerance max(atol, rtol * scale) is refined with the same KSP (see
:mod:`parefg.timestepping.step_solver` for the tolerance).  The helpers here also set up
the KSP of the contact step's Newton solve and of the mass solve: a direct factorization
by default (MUMPS when PETSc has it), checked once for a singular matrix.

The solver *method* (:data:`SOLVER_METHODS`, the scene's ``[solver] method``, ``parefg run
--solver``) names the whole option set: "direct" (the factorization) or "iterative" (CG +
smoothed-aggregation AMG with the rigid-body near-null space).  Its options are offered as
defaults while each KSP reads its options, so any -ksp_/-pc_ option still wins.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from petsc4py import PETSc

from parefg.errors import InputError, SolverError
from parefg.geometry.partition import bisection_parts
from parefg.parallel import default_options, set_from_options
from parefg.petsc_options import EXACT_FACTORIZATIONS

FACTORIZATIONS = ("lu", "cholesky", "ilu", "icc")
#: an iterative KSP stops at this fraction of the step tolerance max(atol, rtol * scale)
#: (true residual): the step check then passes at once, for any scale of the forces
KSP_TOLERANCE_FRACTION = 0.01


@dataclass(frozen=True)
class SolverMethod:
    """A named set of PETSc defaults for the step solves and the mass solve.

    ``step`` are options of the step KSP (read unprefixed: ``ksp_type``, ``pc_type``, ...),
    ``mass`` those of the mass KSP (read with prefix ``mass_``), both without the prefix.
    ``scaled_tolerance``: the step KSP stops at KSP_TOLERANCE_FRACTION of the step
    tolerance, unless -ksp_atol is given.  ``finest_schwarz``: the MLS degrees whose step
    preconditioner (GAMG) gets :func:`configure_finest_schwarz` after each set-up;
    ``finest_blocks``: those whose GAMG's finest level smooths the coarse-trace groups'
    nodes by blocks (:func:`configure_finest_blocks`).
    """

    name: str
    step: dict[str, str] = field(default_factory=dict)
    mass: dict[str, str] = field(default_factory=dict)
    scaled_tolerance: bool = False
    finest_schwarz: tuple[int, ...] = ()
    finest_blocks: tuple[int, ...] = ()

    def finest_level(self, degree: int | None, trace_blocks=None) -> FinestLevel | None:
        """What the step preconditioner's finest level becomes after each set-up, or None.

        ``trace_blocks``: the discretization's (``Discretization.trace_blocks``), used by
        :func:`configure_finest_blocks`.
        """
        if degree in self.finest_schwarz:
            return configure_finest_schwarz
        if degree in self.finest_blocks and trace_blocks is not None:
            return partial(configure_finest_blocks, blocks=trace_blocks)
        return None


#: configures a set-up GAMG's finest level (configure_finest_schwarz, ..._blocks)
FinestLevel = Callable[[PETSc.PC], None]


# Measured (square, step Jacobian, CG to 1e-8; scripts/bench/bench_iterative.py): a
# threshold of 0.05 keeps GAMG from coarsening the wide MLS stencils in one jump (2178 ->
# 18 rows at h = 1/32); the Chebyshev/Jacobi smoother is SPD (SOR's inode blocks hit zero
# pivots on the coarse rigid-body levels); the residual is the true one, so the tolerance
# is on |b - A u|.  The preconditioner is set up again only when the step matrix changes
# (the contact active set), and then keeps its interpolation (the aggregates and
# prolongators of the first Jacobian; only the Galerkin coarse matrices are recomputed) but
# not the smoothed-aggregation eigenvalue estimate: the levels' Chebyshev estimates its
# interval for the new matrix itself.  The contact rows change a thin layer at Gamma_C, to
# which the coarse spaces hardly react, but they raise the largest eigenvalue: with the
# estimate kept (PETSc's default) CG stopped with DIVERGED_INDEFINITE_PC (m = 1, h =
# 1/320, 206082 DOFs, first step; earlier m = 2, s = 3.2, h = 1/16).  Measured with both
# (2026-12-07): the same CG counts (m = 1, 2e5 DOFs: 98 against 96; impact, 258 Jacobians:
# 11763 against 11760; z: 960 against 932) and the step solve 1.46x (m = 1, 2e5 DOFs,
# PCSetUp 9.5 -> 4.6 s), 1.5x (m = 2, 8450 DOFs), 1.4x (m = 3) faster.  A linear solve
# that fails with a kept interpolation is retried once with a new one (ContactStepSolver).
# The counts are bounded in h for supports up to s ~ 2.4 at m = 2 (static 23, 25, 25 at
# h = 1/16, 1/32, 1/64) and grow with 1/h for wider ones (s = 3.2: 448, 803, 1035): a wide
# MLS support makes oscillating nodal parameters give almost no field, so the smallest
# eigenvalues of the Jacobi-scaled matrix (1e-6 of the largest at s = 3.2, about 10 % of
# them below 1e-3) belong to oscillating vectors, which neither a smoother (it damps the
# large eigenvalues) nor a coarse space (smooth) reaches.  No GAMG or BoomerAMG option
# changed that (threshold 0 ... 0.2, square graph, 0-2 prolongator smoothings, coarse
# limit, levels, Chebyshev with 2-8 steps or SOR, a filtered or s = 2.2 Pmat).
_CG = {  # the true residual: the tolerance is on |b - A u|
    "ksp_type": "cg",
    "ksp_norm_type": "unpreconditioned",
    "ksp_rtol": "1e-8",
    "ksp_max_it": "10000",
}
_AMG = {
    **_CG,
    "pc_type": "gamg",
    "pc_gamg_type": "agg",
    "pc_gamg_agg_nsmooths": "1",
    "pc_gamg_threshold": "0.05",
    # The levels smooth with GAMG's own Chebyshev / Jacobi.  No mg_levels_ defaults here:
    # PCMG reads them at set-up, after set_from_options has withdrawn its defaults again.
    "pc_gamg_reuse_interpolation": "true",  # PETSc 3.18's default too; stated, it is relied on
    "pc_gamg_use_sa_esteig": "false",  # Chebyshev estimates each new matrix's interval
}
# At m = 3 (s = 3.2) the oscillating near-null vectors are a band of high frequencies (the
# smallest eigenvalues of the Jacobi-scaled step Jacobian are checkerboard patterns times
# smooth functions): GAMG's counts grow 1.4x per halving of h (246, 346, 416, 423 at h =
# 1/16 ... 1/128, CG to 1e-8 on the step Jacobian).  Local solves on overlapping patches
# remove them: GAMG keeps its coarse levels and its finest level smooths with 3 Chebyshev
# steps on an overlapping additive Schwarz (overlap 1: the matrix graph reaches a whole
# support; a MUMPS Cholesky per block of about SCHWARZ_BLOCK_ROWS rows).  The blocks are
# compact in space (schwarz_blocks): PETSc's own split of one rank's rows is contiguous
# chunks, which gmsh's node numbering (column by column) makes strips of the square, and
# CG per Newton step then grew with 1/h on 1 rank (3.8, 5.8, 8.8 at h = 1/32, 1/64,
# 1/128; 6.0, 5.4, 6.6 on 2 ranks, where PETSc cuts the blocks with its graph
# partitioner).  Compact blocks take 3.8, 5.5, 6.7 with 2 Chebyshev steps and 2.6, 4.0,
# 4.8 with 3, at 0.85x the strips' solve time at 1/128; 4 steps take 3.9 there for 1.1x
# the time of 3.  With the strips, the solve took 0.6-0.9x (1 rank) and 0.17x (2 ranks)
# the time of hypre BoomerAMG with its Schwarz smoothers, the former m = 3 default, which
# took 1.0, 6.4, 27, 16, 15 CG per Newton step on 1 rank (h = 1/8 ... 1/128) but 44, 54,
# 72, 54, 52 on 2 (its Schwarz patches stop at the ranks' interface).  Smaller blocks
# cost more (512 rows: 1.7x the time), larger ones save nothing (4096 rows: 6.7 at 1/128
# with 2 steps); overlap 2 saves 17 % of the iterations for 1.4x the time; a Chebyshev
# interval narrower than GAMG's [0.1, 1.1] x the largest eigenvalue costs iterations;
# PETSc's own Cholesky spent 3x as long in its symbolic phase; ASM on every level hits
# zero pivots on the coarse rigid modes.  PCMG makes its level smoothers at set-up, so
# this is applied after each set-up (configure_finest_schwarz), not through options.
SCHWARZ_BLOCK_ROWS = 2048
_FINEST_SCHWARZ = {
    "ksp_type": "chebyshev",
    "ksp_max_it": "3",
    "pc_type": "asm",
    "pc_asm_type": "basic",
    "pc_asm_overlap": "1",
    "sub_ksp_type": "preonly",
    "sub_pc_type": "cholesky",
    "sub_pc_factor_mat_solver_type": "mumps",
}
#: options prefix (after the KSP's own) of the finest Schwarz smoother: -mg_finest_pc_asm_overlap 2
FINEST_PREFIX = "mg_finest_"


def configure_finest_schwarz(pc: PETSc.PC) -> None:
    """After GAMG ``pc`` was set up: its finest smoother becomes Chebyshev on overlapping
    additive Schwarz (_FINEST_SCHWARZ, blocks of ~SCHWARZ_BLOCK_ROWS rows; any -mg_finest_
    option wins, -mg_finest_pc_asm_blocks included).  Collective.

    A no-op for another PC (a -pc_type given by the user) or a finest level already done
    (the same set-up).  GAMG makes new smoothers at each set-up for a new matrix: call
    this after each.  The smoother is renewed as Richardson and back, so that Chebyshev
    estimates its bounds for ASM instead of keeping those it had for Jacobi.  Its options
    prefix becomes -mg_finest_: -mg_levels_ options no longer reach that level.  A GAMG
    of one level (a tiny matrix) has no smoother to replace: it is left as it is.
    """
    smoother = _finest_smoother(pc, PETSc.PC.Type.ASM)
    if smoother is None:
        return
    prefix = (pc.getOptionsPrefix() or "") + FINEST_PREFIX
    smoother.setOptionsPrefix(prefix)
    rows = smoother.getOperators()[1].getLocalSize()[0]
    with default_options(prefix, _FINEST_SCHWARZ):  # the block solvers are made at set-up
        smoother.setFromOptions()
        asm = smoother.getPC().getType() == PETSc.PC.Type.ASM
        if asm and not PETSc.Options().hasName(prefix + "pc_asm_blocks"):
            n_blocks = max(1, round(rows / SCHWARZ_BLOCK_ROWS))
            blocks = schwarz_blocks(smoother.getOperators()[1], n_blocks)
            smoother.getPC().setASMLocalSubdomains(n_blocks, is_local=blocks)  # overlap added
        smoother.setUp()


def schwarz_blocks(matrix: PETSc.Mat, n_blocks: int) -> list[PETSc.IS] | None:
    """``n_blocks`` compact blocks of ``matrix``'s owned rows: the recursive coordinate
    bisection of the rank partition (:func:`~parefg.geometry.partition.bisection_parts`)
    of this rank's nodes, whose coordinates are read from the rotation of the rigid-body
    near-null space.  Not collective.

    None (PETSc then splits the rows itself) for one block, or a matrix without the
    three rigid-body modes of 2x2 blocks.  The rotation is (-y, x) up to a shift and a
    scale (orthonormalized against the translations): the bisection does not see either.
    """
    modes = matrix.getNearNullSpace()
    if n_blocks == 1 or matrix.getBlockSize() != 2 or not modes or len(modes.getVecs()) != 3:
        return None
    rotation = modes.getVecs()[2].getArray()  # (-y_0, x_0, -y_1, x_1, ...), owned nodes
    points = np.column_stack([rotation[1::2], -rotation[0::2]])  # (n_nodes, 2)
    first = matrix.getOwnershipRange()[0]
    part = bisection_parts(points, n_blocks)  # the rank partition's bisection, on its nodes
    blocks = []
    for block in range(n_blocks):
        nodes = np.flatnonzero(part == block)
        rows = first + 2 * nodes[:, None] + np.arange(2)  # (n_block_nodes, 2): x and y rows
        blocks.append(PETSc.IS().createGeneral(rows.ravel().astype(PETSc.IntType), PETSc.COMM_SELF))
    return blocks


def _finest_smoother(pc: PETSc.PC, configured: str) -> PETSc.KSP | None:
    """The finest-level smoother of a set-up GAMG ``pc``, renewed as Richardson (so that a
    Chebyshev made of it again estimates its bounds for the new PC instead of keeping
    Jacobi's); None for another PC, a GAMG of one level, or a smoother whose PC is already
    of type ``configured`` (the same set-up, done).  Not collective."""
    if pc.getType() != PETSc.PC.Type.GAMG or pc.getMGLevels() < 2:
        return None
    smoother = pc.getMGSmoother(pc.getMGLevels() - 1)
    if smoother.getPC().getType() == configured:
        return None
    smoother.setType(PETSc.KSP.Type.RICHARDSON)
    return smoother


def configure_finest_blocks(pc: PETSc.PC, blocks: list[np.ndarray]) -> None:
    """After GAMG ``pc`` was set up: its finest smoother becomes Chebyshev on Jacobi plus
    exact solves on ``blocks`` (additive; this rank's global node ids of each coarse-trace
    group, :attr:`Discretization.trace_blocks`).  Collective.

    Why: a Nitsche part on the coarse trace constrains only P u, so a nodal checkerboard
    at its edge has little energy while the diagonal keeps the whole beta; Jacobi cannot
    smooth it and aggregation cannot represent it, and GAMG's CG counts grew with 1/h
    (m = 2: 26, 32, 40, 46 at h = 1/16 ... 1/128, CG to 1e-8 on the step Jacobian).  The
    group's nodes solved together remove it: 21, 21, 21, 22, in less time (0.29 s
    against 0.70 s at 1/128), m = 1 alike (README, Iterative solver).  A no-op for another
    PC, a GAMG of one level, or a finest level already done.
    """
    smoother = _finest_smoother(pc, PETSc.PC.Type.COMPOSITE)
    if smoother is None:
        return
    steps = smoother.getTolerances()[3]
    smoother.setType(PETSc.KSP.Type.CHEBYSHEV)
    smoother.setTolerances(max_it=steps)
    composite = smoother.getPC()
    composite.setType(PETSc.PC.Type.COMPOSITE)
    composite.setCompositeType(PETSc.PC.CompositeType.ADDITIVE)
    composite.addCompositePCType(PETSc.PC.Type.JACOBI)
    composite.addCompositePCType(PETSc.PC.Type.ASM)
    schwarz = composite.getCompositePC(1)
    if not blocks:  # PCASM wants a block on every rank: a rank off the parts, its first node
        blocks = [np.array([smoother.getOperators()[1].getOwnershipRange()[0] // 2])]
    sets = [
        PETSc.IS().createGeneral(
            (2 * nodes[:, None] + np.arange(2)).ravel().astype(PETSc.IntType), PETSc.COMM_SELF
        )
        for nodes in blocks
    ]
    schwarz.setASMLocalSubdomains(len(sets), sets, sets)
    schwarz.setASMOverlap(0)
    schwarz.setASMType(PETSc.PC.ASMType.BASIC)  # symmetric, for CG
    smoother.setUp()
    for block in schwarz.getASMSubKSP():
        block.setType(PETSc.KSP.Type.PREONLY)
        block.getPC().setType(PETSc.PC.Type.LU)
    smoother.setUp()


def keeps_interpolation(ksp: PETSc.KSP, method: SolverMethod) -> bool:
    """Whether ``ksp``'s preconditioner is GAMG keeping its interpolation for a new matrix
    (-pc_gamg_reuse_interpolation: the method's default, else PETSc 3.18's, true).  Call
    after setFromOptions.  Not collective: every rank has the same options."""
    if ksp.getPC().getType() != PETSc.PC.Type.GAMG:
        return False
    default = method.step.get("pc_gamg_reuse_interpolation", "true") == "true"
    options = PETSc.Options(ksp.getOptionsPrefix())
    return bool(options.getBool("pc_gamg_reuse_interpolation", default))


def set_up_afresh(ksp: PETSc.KSP, method: SolverMethod, finest: FinestLevel | None) -> None:
    """The step KSP's preconditioner built anew for its current operators (a GAMG hierarchy
    with new aggregates, interpolation and levels), then :func:`set_up_step_ksp`.

    The PC's type is set away and back, which destroys its hierarchy; its options (the
    ``method``'s defaults, any -pc_ option winning) are read again.  A PCReset would keep
    the level solvers, which refuse the other sizes of new aggregates.  Collective.
    """
    pc = ksp.getPC()
    kind = pc.getType()
    pc.setType(PETSc.PC.Type.NONE)
    pc.setType(kind)
    set_from_options(pc, pc.getOptionsPrefix() or "", method.step)
    # the operators set again: a KSP set up for them skips the set-up of its new PC
    ksp.setOperators(*ksp.getOperators())
    set_up_step_ksp(ksp, finest)


def set_up_step_ksp(ksp: PETSc.KSP, finest: FinestLevel | None) -> None:
    """Set the step KSP up for its current operators (:func:`set_up_factored`), then
    (``finest``, from :meth:`SolverMethod.finest_level`) its GAMG's finest level.
    Collective."""
    set_up_factored(ksp)
    if finest is not None:
        finest(ksp.getPC())


# MUMPS INFOG(1) when the workspace its analysis estimated was too small (-8, -9): its
# parallel orderings can need more than the default relaxation ICNTL(14) = 20 %.  Measured:
# the mass matrix at m = 2, support 2.4, h = 1/64 on 2 ranks (Cholesky, AMF ordering)
# failed with INFOG(1) = -9 and factors with 30 %; a run pays the larger workspace only
# where the estimate was short.
SHORT_WORKSPACE = (-8, -9)
WORKSPACE_RETRIES = 3
DEFAULT_RELAXATION = 20  # MUMPS's ICNTL(14), in percent


def set_up_factored(ksp: PETSc.KSP) -> None:
    """``ksp.setUp()``; a MUMPS factorization short of workspace is redone with ICNTL(14)
    doubled (at least DEFAULT_RELAXATION; up to WORKSPACE_RETRIES times; the option
    -<prefix>mat_mumps_icntl_14 keeps the value for the KSP's later factorizations).
    Collective."""
    ksp.setUp()
    for _ in range(WORKSPACE_RETRIES):
        if not _relaxed_workspace(ksp):
            return
        ksp.setUp()


def _relaxed_workspace(ksp: PETSc.KSP) -> bool:
    """If the KSP's MUMPS factorization failed for want of workspace: ICNTL(14) doubled in
    the options, the PC reset to be set up again; whether it was.  Collective (INFOG is
    the same on every rank)."""
    pc = ksp.getPC()
    if pc.getType() not in EXACT_FACTORIZATIONS or pc.getFactorSolverType() != "mumps":
        return False
    factor = pc.getFactorMatrix()
    if factor.getMumpsInfog(1) not in SHORT_WORKSPACE:
        return False
    relaxation = max(2 * factor.getMumpsIcntl(14), DEFAULT_RELAXATION)  # 0 doubled stays 0
    PETSc.Options().setValue(f"{ksp.getOptionsPrefix() or ''}mat_mumps_icntl_14", relaxation)
    operators = ksp.getOperators()
    pc.reset()  # drops the factor and the operators: set both again
    ksp.setOperators(*operators)
    return True


# The mass matrix is SPD with no near-null space: CG + Jacobi.  Measured (true residual
# to 1e-13, where it stalls near 1e-11): 76 iterations at s = 2.2 (m = 2, h = 1/64), but
# 4809 / 9524 at the default s = 3.2 (h = 1/32, 1/64) and 10102 at m = 3 (h = 1/32); GAMG
# needs a third of those at twice the cost each.  The solve is done once (u_0, v_0, a_0).
_MASS = {
    "ksp_type": "cg",
    "ksp_norm_type": "unpreconditioned",
    "ksp_rtol": "1e-10",
    "ksp_max_it": "20000",
    "pc_type": "jacobi",
}
#: solver method name -> its option set; the scene schema reads the names
SOLVER_METHODS = {
    "direct": SolverMethod("direct"),
    "iterative": SolverMethod(
        "iterative",
        step=_AMG,
        mass=_MASS,
        scaled_tolerance=True,
        finest_schwarz=(3,),
        finest_blocks=(1, 2),
    ),
}
DEFAULT_SOLVER_METHOD = "direct"


# PETSc's Krylov methods and preconditioners that assume a symmetric operator: with VCI's
# nonsymmetric K they would solve another system (a Cholesky factor reads one triangle).
SYMMETRIC_KSPS = (
    "cg", "cr", "minres", "symmlq", "pipecg", "pipecr", "groppcg", "pipecgrr", "fcg",
    "pipefcg", "stcg", "nash", "gltr", "qcg",
)  # fmt: skip
SYMMETRIC_PCS = ("cholesky", "icc")
# preconditioners whose blocks are solved by a -sub_ksp_type / -sub_pc_type solver
BLOCK_PCS = ("bjacobi", "asm", "gasm")


def check_symmetric_use(ksp: PETSc.KSP, symmetric: bool) -> None:
    """InputError if the configured KSP or PC, or a block solver's (-sub_ksp_type,
    -sub_pc_type), needs a symmetric operator and it is not.

    The scene loader already chooses Gauss integration for such solvers
    (parefg.scene.schema.wants_symmetric); this catches the rest (options set in-process,
    an options file).  Call after setFromOptions.  Not collective: every rank has the
    same options.
    """
    if symmetric:
        return
    pc = ksp.getPC().getType()
    chosen = [("KSP", ksp.getType()), ("PC", pc)]
    if pc in BLOCK_PCS:  # their block solvers are made at setUp, from the -sub_ options
        options = PETSc.Options(ksp.getOptionsPrefix())
        chosen += [
            ("block KSP", options.getString("sub_ksp_type", "")),
            ("block PC", options.getString("sub_pc_type", "")),
        ]
    assumes_symmetry = [
        f"{what} {name}" for what, name in chosen if name in SYMMETRIC_KSPS + SYMMETRIC_PCS
    ]
    if assumes_symmetry:
        needs = ", ".join(assumes_symmetry)
        raise InputError(
            f"the step solver ({needs}) needs a symmetric matrix, but "
            'discretization.integration = "vci" makes the stiffness nonsymmetric: use LU '
            '(the direct solver\'s default) or set discretization.integration = "gauss"'
        )


def configure_linear_solver(ksp: PETSc.KSP, symmetric: bool = True) -> None:
    """Default: a direct MUMPS factorization, Cholesky (LU for a ``symmetric`` False
    operator: VCI's stiffness); any -ksp_/-pc_ option overrides it.

    A Cholesky factorization of a nonsymmetric matrix reads one triangle only: it solves
    another system, which the exact-step shortcut of the step solvers would accept without
    evaluating its residual (measured with VCI on the Z, m = 3: 1 and 2 ranks then
    disagreed by 3.5e-4 of the L2 error).
    """
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.CHOLESKY if symmetric else PETSc.PC.Type.LU)
    pc.setFactorSolverType("mumps")


def scaled_ksp_tolerance(method: SolverMethod) -> bool:
    """Whether the step KSP's atol follows the step tolerance (no -ksp_atol given)."""
    return method.scaled_tolerance and not PETSc.Options().hasName("ksp_atol")


def set_ksp_tolerance(ksp: PETSc.KSP, step_tolerance: float) -> None:
    """KSP atol = KSP_TOLERANCE_FRACTION * the step tolerance (rtol etc. kept).  Not collective."""
    ksp.setTolerances(atol=KSP_TOLERANCE_FRACTION * step_tolerance)


def check_factorization(ksp: PETSc.KSP, matrix: PETSc.Mat) -> None:
    """Fail now, not at the first solve, if the chosen factorization package does not exist.

    PETSc looks the package (-pc_factor_mat_solver_type) up only when the preconditioner
    is set up, at the first solve.  A 2-row-per-rank matrix of ``matrix``'s type factored
    with the same preconditioner and package raises the same PETSc error right away, for
    the cost of nothing.  Call after setFromOptions.  Collective.
    """
    pc = ksp.getPC()
    if pc.getType() not in FACTORIZATIONS:
        return
    probe = PETSc.Mat().create(matrix.getComm())
    probe.setSizes(((2, None), (2, None)), bsize=2)
    probe.setType(matrix.getType())
    probe.setPreallocationNNZ(1)
    start, stop = probe.getOwnershipRange()
    for row in range(start, stop):
        probe.setValue(row, row, 1.0)
    probe.assemble()
    probe.setOption(PETSc.Mat.Option.SPD, True)
    trial = PETSc.KSP().create(matrix.getComm())
    trial.setOperators(probe)
    trial.setType(PETSc.KSP.Type.PREONLY)
    trial.getPC().setType(pc.getType())
    package = pc.getFactorSolverType()
    if package:
        trial.getPC().setFactorSolverType(package)
    try:
        trial.setUp()
    finally:
        trial.destroy()
        probe.destroy()


DEFAULT_TOLERANCES = {"rtol": 1e-10, "atol": 1e-50, "stol": 1e-13, "max_it": 200}
INEXACT_HINT = "inexact linear solve? tighten -ksp_rtol or use the default direct solver"


def is_exact(ksp: PETSc.KSP) -> bool:
    """True when ``ksp`` solves exactly (to round-off): preonly with an LU or Cholesky PC.

    Read from the types in use, so call after setFromOptions.  ILU/ICC, any Krylov method
    and any other PC are inexact.  Not collective.
    """
    return ksp.getType() == PETSc.KSP.Type.PREONLY and ksp.getPC().getType() in (
        EXACT_FACTORIZATIONS
    )


def step_scale(a_const: PETSc.Mat, b: PETSc.Vec, u0: PETSc.Vec, work: PETSc.Vec) -> float:
    """max(|b|, |A_const u_0|): the forces of a step without contact.  Collective.

    The step tolerance is rtol times this scale: it does not grow with the contact penalty,
    unlike |F(u_0)| (alpha times the predictor's penetration), and it is not zero when only
    the initial guess carries the step (b = 0, u_0 != 0).
    """
    a_const.mult(u0, work)
    return max(b.norm(), work.norm())


def ksp_failure(ksp: PETSc.KSP) -> str:
    return f"KSP reason {reason_name(PETSc.KSP.ConvergedReason, ksp.getConvergedReason())}"


class LinearStepSolver:
    """u = A^-1 b with one factorization (or preconditioner) reused by every step.  Collective.

    The answer is checked like a Newton step's: the residual |b - A u| must meet
    max(atol, rtol * step_scale) with the SNES tolerances (-snes_rtol, -snes_atol,
    -snes_max_it).  An exact solve meets it at once; an iterative KSP that stopped at its
    own, looser tolerance is refined (u += A^-1 r, the same KSP) until it does, and a sweep
    that does not reduce the residual is a failure.
    """

    def __init__(
        self,
        comm,
        a_const: PETSc.Mat,
        method: str = DEFAULT_SOLVER_METHOD,
        symmetric: bool = True,
        degree: int | None = None,
        trace_blocks=None,
    ):
        """``degree``: the MLS degree, whose preconditioner the method may adapt, with the
        discretization's ``trace_blocks`` (:meth:`SolverMethod.finest_level`)."""
        self.a_const = a_const
        self.finest = SOLVER_METHODS[method].finest_level(degree, trace_blocks)
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOperators(a_const)
        configure_linear_solver(self.ksp, symmetric)
        # the step's options are the unprefixed ones (-ksp_type, as for the contact step)
        set_from_options(self.ksp, "", SOLVER_METHODS[method].step)
        self.scaled_tolerance = scaled_ksp_tolerance(SOLVER_METHODS[method])
        check_symmetric_use(self.ksp, symmetric)
        check_factorization(self.ksp, a_const)
        self.exact = is_exact(self.ksp)
        options = PETSc.Options()
        self.rtol = options.getReal("snes_rtol", DEFAULT_TOLERANCES["rtol"])
        self.atol = options.getReal("snes_atol", DEFAULT_TOLERANCES["atol"])
        self.max_sweeps = options.getInt("snes_max_it", DEFAULT_TOLERANCES["max_it"])
        self._residual, self._correction = a_const.createVecLeft(), a_const.createVecRight()
        self.factorizations = 0
        self.jacobian_builds = 0
        self.residual_norm = self.tolerance = float("nan")  # of the last step

    def solve(self, b: PETSc.Vec, u: PETSc.Vec, t: float) -> tuple[int, int]:
        """Solve A u = b to the step tolerance from the guess u (overwritten).  Collective."""
        if self.factorizations == 0:
            set_up_step_ksp(self.ksp, self.finest)
            self.factorizations = 1
        self.tolerance = max(self.atol, self.rtol * step_scale(self.a_const, b, u, self._residual))
        if self.scaled_tolerance:
            set_ksp_tolerance(self.ksp, self.tolerance)
        self._solve(b, u, t)
        linear, previous = self.ksp.getIterationNumber(), np.inf
        for _ in range(self.max_sweeps):
            residual = self._residual
            self.a_const.mult(u, residual)
            residual.aypx(-1.0, b)  # b - A u
            self.residual_norm = residual.norm()
            if self.residual_norm <= self.tolerance:
                return 0, linear
            if not self.residual_norm < previous:  # also catches NaN
                break
            previous = self.residual_norm
            self._solve(residual, self._correction, t)
            u.axpy(1.0, self._correction)
            linear += self.ksp.getIterationNumber()
        raise SolverError(
            f"linear solve failed at t = {t:.6g}: residual {self.residual_norm:.3g} above the "
            f"step tolerance {self.tolerance:.3g} after {linear} linear iterations "
            f"({INEXACT_HINT})"
        )

    def _solve(self, rhs: PETSc.Vec, out: PETSc.Vec, t: float) -> None:
        self.ksp.solve(rhs, out)
        if self.ksp.getConvergedReason() < 0:
            raise SolverError(f"linear solve failed at t = {t:.6g}: {ksp_failure(self.ksp)}")


def reason_name(reasons, reason: int) -> str:
    """``NAME (code)`` of a PETSc converged-reason code, from its enum class ``reasons``."""
    names = {v: k for k, v in vars(reasons).items() if isinstance(v, int)}
    return f"{names.get(reason, 'UNKNOWN')} ({reason})"
