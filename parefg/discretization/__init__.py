"""The EFG discretization: MLS shape functions on the node cloud, their weights, the
background-cell quadrature, sparse assembly into PETSc matrices, and the size budget
(:mod:`.size_estimate` counts a run before it is built, :mod:`.budget` refuses it).

:mod:`.operators` builds a :class:`~parefg.discretization.operators.Discretization` (mass,
stiffness; the boundary operators in :mod:`.boundary_operators`, the point operators in
:mod:`.point_set`) from a scene; everything else here is what it is made of.
The collectives and PETSc helpers it uses are in :mod:`parefg.parallel`.
"""
