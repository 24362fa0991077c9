"""The boundary operators of a discretization: boundary point sets, Dirichlet parts and D, Gamma_C.

A mixin of the builder of :mod:`parefg.discretization.operators`: the Gauss points of each
boundary part, the Dirichlet operator D of each part's method (penalty or Nitsche,
:mod:`parefg.discretization.dirichlet`) with its beta, and the Gamma_C point set with the
sparsity pattern of the contact coupling.  Every method is collective.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from parefg.boundary import BoundaryKind
from parefg.discretization import coarse_trace
from parefg.discretization.assembly import interleaved
from parefg.discretization.dirichlet import (
    COARSE_CONTACT_METHODS,
    DIRICHLET_METHODS,
    HAT_CONTACT_METHODS,
    NITSCHE_CONTACT_METHODS,
    DirichletPart,
    local_operators,
    traction_operator,
)
from parefg.discretization.mls import MLS, ShapeValues
from parefg.discretization.point_set import PointSet
from parefg.discretization.quadrature import Quadrature, segment_quadrature
from parefg.discretization.structure import structural_sum, weighted_product
from parefg.discretization.trace_inverse import nitsche_beta
from parefg.geometry.cloud import NodeCloud
from parefg.geometry.partition import Partition
from parefg.parallel import petsc_matrix
from parefg.profiling import phase


class BoundaryOperators:
    """Boundary point sets and D of the builder (which provides the attributes below)."""

    comm: Any
    scene: Any
    cloud: NodeCloud
    partition: Partition
    mls: MLS
    timings: dict[str, float]
    n_nodes: int  # global
    n_held: int  # the nodes the rank holds: the index space of the matrices built here
    owned_nodes: slice  # this rank's own nodes among them
    n_dofs_local: int
    n_contact: int
    node_range: tuple[int, int]
    trace_blocks: list[np.ndarray]

    def _shape(self, points: np.ndarray, gradients: bool) -> ShapeValues:
        raise NotImplementedError  # the builder's: MLS at this rank's points

    def _point_set(
        self, quadrature, shape, gradients=False, keep_gradients=False, **extra
    ) -> PointSet:
        raise NotImplementedError  # the builder's: the PointSet of a quadrature

    def _global_dof_columns(self, local: sp.csr_matrix) -> sp.csr_matrix:
        raise NotImplementedError  # the builder's: held DOF columns -> global ones

    def _grouping(self) -> dict[int, int]:
        """Segments per coarse-trace group of each part the scene takes by groups (by part
        id): the Dirichlet parts of a coarse method and the projected contact parts, as
        :meth:`_boundaries` groups them.  Not collective."""
        grouping = {}
        for name, bc in self.scene.boundaries.items():
            part_id = self.cloud.part_names.index(name)
            if bc.kind == BoundaryKind.DIRICHLET and DIRICHLET_METHODS[bc.method].coarse:
                grouping[part_id] = coarse_trace.CHUNK_SEGMENTS
            if bc.kind == BoundaryKind.CONTACT and bc.method in COARSE_CONTACT_METHODS:
                grouping[part_id] = coarse_trace.CHUNK_SEGMENTS
            if bc.kind == BoundaryKind.CONTACT and bc.method in HAT_CONTACT_METHODS:
                grouping[part_id] = coarse_trace.HAT_SEGMENTS
        return grouping

    def _boundary_quadrature(self, part_ids: list[int], grouped=(), hat_parts=()):
        """This rank's Gauss points on segments of the given parts, and their global rows.

        Segments of the parts in ``grouped`` are taken by coarse-trace groups
        (:func:`~parefg.discretization.coarse_trace.trace_groups`, numbered on the whole
        part, as every rank holds the segments; of HAT_SEGMENTS segments on the parts in
        ``hat_parts``, else CHUNK_SEGMENTS): a group belongs to the owner of its
        lowest segment, so its projection is local and does not depend on the partition,
        and its segments come together in chain order.  Returns (quadrature, rows,
        group, offset), the last two per point (group -1 on the other parts).
        """
        cloud, part = self.cloud, self.partition
        on_parts = np.isin(cloud.segment_part, part_ids)
        # global, rank-independent numbering of the selected segments (for output rows)
        global_index = np.cumsum(on_parts) - 1
        group = np.full(len(cloud.segments), -1, dtype=np.int64)
        offset = np.zeros(len(cloud.segments))
        for part_id in grouped:
            on_part = np.flatnonzero(cloud.segment_part == part_id)
            part_group, offset[on_part] = coarse_trace.trace_groups(
                cloud.coords,
                cloud.segments,
                on_part,
                coarse_trace.HAT_SEGMENTS if part_id in hat_parts else coarse_trace.CHUNK_SEGMENTS,
            )
            group[on_part] = part_group + group.max() + 1
        owner = part.segment_owner.copy()
        in_group = np.flatnonzero(group >= 0)
        first = np.full(group.max() + 1, len(cloud.segments))
        np.minimum.at(first, group[in_group], in_group)
        owner[in_group] = owner[first[group[in_group]]]
        mine = np.flatnonzero(on_parts & (owner == self.comm.rank))
        mine = mine[np.lexsort((offset[mine], group[mine]))]  # stable: the rest in id order
        n_gauss = self.scene.discretization.quadrature
        quadrature = segment_quadrature(cloud.coords, cloud.segments, n_gauss, segment_ids=mine)
        rows = global_index[quadrature.cell] * n_gauss + np.arange(len(quadrature.cell)) % n_gauss
        return quadrature, rows, group[quadrature.cell], offset[quadrature.cell]

    def _boundaries(self):
        """Point sets of every boundary condition; D, its parts and the Gamma_C pattern."""
        scene, cloud, n = self.scene, self.cloud, self.n_held
        boundary, parts, contact_parts = {}, {}, []
        dirichlet_terms: list[tuple[float, sp.spmatrix]] = []  # (sign, matrix) summing to D
        for name, bc in scene.boundaries.items():
            part_id = cloud.part_names.index(name)
            if bc.kind == BoundaryKind.CONTACT:
                contact_parts.append(part_id)
                continue
            method = DIRICHLET_METHODS[bc.method] if bc.kind == BoundaryKind.DIRICHLET else None
            coarse = method is not None and method.coarse
            quadrature, _, group, offset = self._boundary_quadrature(
                [part_id], grouped=[part_id] if coarse else []
            )
            consistent = method is not None and method.consistent
            shape = self._shape(quadrature.points, gradients=consistent)
            with phase(self.timings, "assembly"):
                boundary[name] = self._point_set(quadrature, shape)
            if method is not None:
                parts[name], local = self._dirichlet_part(
                    method, bc, quadrature, shape, (group, offset) if coarse else None
                )
                dirichlet_terms.append((1.0, local))
        contact, pattern = None, sp.csr_matrix((2 * n, 2 * n))
        if contact_parts:
            nitsche_parts = self._nitsche_contact_parts(NITSCHE_CONTACT_METHODS)
            coarse_parts = self._nitsche_contact_parts(COARSE_CONTACT_METHODS)
            hat_parts = self._nitsche_contact_parts(HAT_CONTACT_METHODS)
            quadrature, rows, group, offset = self._boundary_quadrature(
                contact_parts, grouped=coarse_parts + hat_parts, hat_parts=hat_parts
            )
            part_of_point = cloud.segment_part[quadrature.cell]
            on_hat = np.isin(part_of_point, hat_parts)
            on_contact = np.isin(cloud.segment_part, contact_parts)  # every rank's segments
            self.n_contact = (
                int(np.count_nonzero(on_contact)) * self.scene.discretization.quadrature
            )
            shape = self._shape(quadrature.points, gradients=bool(nitsche_parts))
            self._add_trace_blocks(shape, group)
            extra = {}
            if nitsche_parts:
                # the polynomial coarse trace projects the law's traction too (and makes
                # gamma constant on a group); the hats project u and the gap only
                polynomial_group = np.where(on_hat, -1, group)
                projection = None
                if coarse_parts:
                    projection = coarse_trace.projection(
                        quadrature, cloud.coords, cloud.segments, polynomial_group, offset
                    )
                extra = self._nitsche_contact(
                    quadrature, shape, part_of_point, nitsche_parts, polynomial_group, projection
                )
                if hat_parts:  # block-diagonal, on other points than the polynomial one
                    hat_group = np.where(on_hat, group, -1)
                    hats = coarse_trace.hat_projection(
                        quadrature, cloud.coords, cloud.segments, hat_group, offset
                    )
                    extra["projection"] = hats if projection is None else projection @ hats
                dirichlet_terms.append((-1.0, extra.pop("nitsche_matrix")))
            with phase(self.timings, "assembly"):
                contact = self._point_set(quadrature, shape, part=part_of_point, rows=rows, **extra)
                pattern = contact_pattern(shape, n, group, n_global=self.n_nodes)
        dirichlet_local = structural_sum(dirichlet_terms, (2 * n, 2 * n))
        return boundary, parts, contact, dirichlet_local, pattern

    def _nitsche_contact_parts(self, methods: tuple[str, ...]) -> list[int]:
        """Part ids of the contact parts imposed by one of ``methods``."""
        cloud, scene = self.cloud, self.scene
        return [
            cloud.part_names.index(name)
            for name, bc in scene.boundaries.items()
            if bc.kind == BoundaryKind.CONTACT and bc.method in methods
        ]

    def _nitsche_contact(
        self, quadrature, shape, part_of_point, nitsche_parts, group, projection
    ) -> dict:
        """sigma_nu(u_h) at the Gamma_C points, gamma, and N = T_nu^T W gamma^-1 T_nu.

        Chouly & Hild's symmetric Nitsche contact (parefg.mechanics.contact) is the
        penalty law with alpha_C = gamma on u_nu - sigma_nu / gamma, plus -N in the
        stiffness.  gamma is the part's safety times the coercivity bound of each segment
        (the Dirichlet parts' bound, shared with them where a cell has both): then
        a(v, v) - ||sigma_nu(v)||^2 / gamma >= (1 - 1 / (2 safety)) a(v, v).  Points of
        penalty contact parts get zero traction rows and gamma = alpha_C.

        As on the Dirichlet parts, the law acts on the coarse trace (``projection`` P,
        each point's ``group``): T_nu -> P T_nu here, u -> P u in the contact frame, gamma
        the largest of its group's, so that P and gamma commute.  Its error is then flat
        in the safety; a pointwise law over-constrains the MLS trace as gamma grows.
        """
        scene, n = self.scene, self.n_held
        lam, mu = scene.material.lam, scene.material.mu
        n_gauss = scene.discretization.quadrature
        with phase(self.timings, "assembly"):  # the trace-inverse estimate
            segments = quadrature.cell[::n_gauss]  # points come by segment, n_gauss each
            per_segment = nitsche_beta(
                self.mls,
                self.cloud,
                self._nitsche_segments(),
                segments,
                scene.discretization.quadrature,
                lam,
                mu,
                edge_values=(quadrature.points, shape),
            )
        safety = np.zeros(len(self.cloud.part_names))
        for name, bc in scene.boundaries.items():
            if bc.kind == BoundaryKind.CONTACT and bc.method in NITSCHE_CONTACT_METHODS:
                safety[self.cloud.part_names.index(name)] = bc.safety
        segment_of_point = np.repeat(np.arange(len(segments)), n_gauss)
        nitsche = np.isin(part_of_point, nitsche_parts)
        gamma = safety[part_of_point] * per_segment[segment_of_point]
        gamma = coarse_trace.group_largest(gamma, group)
        gamma = np.where(nitsche, gamma, scene.penalty.alpha_contact)
        with phase(self.timings, "assembly"):
            assert quadrature.normals is not None
            traction = traction_operator(shape, quadrature.normals, n, lam, mu)
            if projection is not None:
                traction = coarse_trace.project_rows(projection, traction)
            normals = quadrature.normals * nitsche[:, None]  # zero rows off Nitsche parts
            rotate = sp.csr_matrix(
                (
                    normals.ravel(),
                    (np.repeat(np.arange(len(normals)), 2), np.arange(2 * len(normals))),
                ),
                shape=(len(normals), 2 * len(normals)),
            )
            normal_traction = (rotate @ traction).tocsr()  # (n_c, 2 n) sigma_nu rows
            matrix = weighted_product(normal_traction, quadrature.weights / gamma, normal_traction)
            # PETSc, as the point set's value operator: no scipy twin is kept
            normal_traction = petsc_matrix(
                self.comm,
                self._global_dof_columns(normal_traction),
                self.n_dofs_local,
                2 * self.n_nodes,
            )
        return {
            "normal_traction": normal_traction,
            "gamma": gamma,
            "nitsche_matrix": matrix,
            "projection": projection,
        }

    def _dirichlet_part(self, method, bc, quadrature: Quadrature, shape: ShapeValues, groups):
        """One Dirichlet part by ``method``, and its local contributions to D.

        beta is alpha_D for the penalty, the part's safety times the coercivity bound of
        each segment (:func:`~parefg.discretization.trace_inverse.nitsche_beta`) for Nitsche,
        the largest of its group's for the coarse trace (``groups`` = (group, offset) of
        each point, else None): ||P sigma(v) n|| <= ||sigma(v) n|| on a group, so the
        bound holds for the projected form.
        """
        scene, n = self.scene, self.n_held
        if method.consistent:
            with phase(self.timings, "assembly"):  # the trace-inverse estimate
                per_segment = bc.safety * nitsche_beta(
                    self.mls,
                    self.cloud,
                    self._nitsche_segments(),
                    quadrature.cell[:: scene.discretization.quadrature],  # by segment
                    scene.discretization.quadrature,
                    scene.material.lam,
                    scene.material.mu,
                    edge_values=(quadrature.points, shape),
                )
            beta = np.repeat(per_segment, scene.discretization.quadrature)
        else:
            beta = np.full(len(quadrature.weights), scene.penalty.alpha_dirichlet)
        projection = None
        if groups is not None:
            group, offset = groups
            self._add_trace_blocks(shape, group)
            beta = coarse_trace.group_largest(beta, group)
            projection = coarse_trace.projection(
                quadrature, self.cloud.coords, self.cloud.segments, group, offset
            )
        with phase(self.timings, "assembly"):
            assert quadrature.normals is not None
            local, load, traction = local_operators(
                method,
                shape,
                quadrature.weights,
                quadrature.normals,
                beta,
                n,
                scene.material.lam,
                scene.material.mu,
                projection,
            )
            part = DirichletPart(
                method=method.name,
                weights=quadrature.weights,
                beta=beta,
                load=petsc_matrix(
                    self.comm, self._global_dof_columns(load), self.n_dofs_local, 2 * self.n_nodes
                ),
                traction=None
                if traction is None
                else petsc_matrix(
                    self.comm,
                    self._global_dof_columns(traction),
                    self.n_dofs_local,
                    2 * self.n_nodes,
                ),
                projection=projection,
            )
        return part, local

    def _add_trace_blocks(self, shape: ShapeValues, group: np.ndarray) -> None:
        """Append the owned nodes that each coarse-trace group's points reach (group >= 0),
        one block per group, to ``trace_blocks``.  Not collective."""
        start = self.node_range[0]
        owned = reached_nodes(shape, group, self.n_held)[:, self.owned_nodes].tocsr()
        blocks = np.split(owned.indices + start, owned.indptr[1:-1])  # one per group number
        self.trace_blocks.extend(block for block in blocks if len(block))  # others' are empty

    def _nitsche_segments(self) -> np.ndarray:
        """Every segment (all ranks) of a part imposed by Nitsche's method (Dirichlet, contact)."""
        cloud, names = self.cloud, []
        for name, bc in self.scene.boundaries.items():
            if bc.kind == BoundaryKind.DIRICHLET and DIRICHLET_METHODS[bc.method].consistent:
                names.append(cloud.part_names.index(name))
            if bc.kind == BoundaryKind.CONTACT and bc.method in NITSCHE_CONTACT_METHODS:
                names.append(cloud.part_names.index(name))
        return np.flatnonzero(np.isin(cloud.segment_part, names))


def contact_pattern(
    shape: ShapeValues, n_nodes: int, group: np.ndarray, n_global: int | None = None
) -> sp.csr_matrix:
    """The (2 n_nodes)^2 pattern (explicit zeros) of every contact Jacobian of the points
    (``n_nodes`` the nodes ``shape`` numbers; ``n_global`` the cloud's, for the kernels).

    A point of a coarse-trace group (``group`` >= 0) reaches, through P, every node of
    its group's points: the group couples all pairs of those nodes, in both components.
    Any other point couples the nodes it shares.  The Nitsche matrix of the coarse law
    has these entries too, but not all of them (with lambda = 0, sigma_nu has no u_x
    part while the tangential rows do), so the pattern cannot rely on it.  Not collective.
    """
    row_of_point = np.where(group >= 0, group, group.max(initial=-1) + 1 + np.arange(len(group)))
    _, row_of_point = np.unique(row_of_point, return_inverse=True)
    incidence = reached_nodes(shape, row_of_point, n_nodes)
    coupled = (incidence.T @ incidence).tocsr()  # counts >= 1: no zero is dropped
    coupled.sort_indices()
    blocks = np.zeros((coupled.nnz, 2, 2))
    return interleaved(coupled.indptr, coupled.indices, blocks, n_global=n_global)


def reached_nodes(shape: ShapeValues, row_of_point: np.ndarray, n_nodes: int) -> sp.csr_matrix:
    """(rows x n_nodes) incidence: the nodes the points of each row reach (their MLS
    neighbours), sorted, as counts >= 1; rows 0 ... row_of_point.max(), points of row -1
    left out.  Not collective."""
    point, slot = np.nonzero(shape.mask)
    kept = row_of_point[point] >= 0
    point, slot = point[kept], slot[kept]
    incidence = sp.csr_matrix(
        (np.ones(len(point)), (row_of_point[point], shape.neighbours[point, slot])),
        shape=(row_of_point.max(initial=-1) + 1, n_nodes),
    )
    incidence.sum_duplicates()  # sorted indices, one entry per node
    return incidence
