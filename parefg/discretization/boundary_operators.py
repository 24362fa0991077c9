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
from parefg.discretization.assembly import Coupling
from parefg.discretization.dirichlet import (
    DIRICHLET_METHODS,
    DirichletPart,
    local_operators,
    traction_operator,
)
from parefg.discretization.mls import MLS, ShapeValues
from parefg.discretization.point_set import PointSet
from parefg.discretization.quadrature import Quadrature, segment_quadrature
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
    n_nodes: int
    n_dofs_local: int
    n_contact: int

    def _shape(self, points: np.ndarray, gradients: bool) -> ShapeValues:
        raise NotImplementedError  # the builder's: MLS at this rank's points

    def _point_set(
        self, quadrature, shape, gradients=False, keep_gradients=False, **extra
    ) -> PointSet:
        raise NotImplementedError  # the builder's: the PointSet of a quadrature

    def _boundary_quadrature(self, part_ids: list[int]) -> tuple[Quadrature, np.ndarray]:
        """This rank's Gauss points on segments of the given parts, and their global rows."""
        cloud, part = self.cloud, self.partition
        on_parts = np.isin(cloud.segment_part, part_ids)
        # global, rank-independent numbering of the selected segments (for output rows)
        global_index = np.cumsum(on_parts) - 1
        mine = np.flatnonzero(on_parts & (part.segment_owner == self.comm.rank))
        quadrature = segment_quadrature(
            cloud.coords, cloud.segments, self.scene.discretization.quadrature, segment_ids=mine
        )
        n_gauss = self.scene.discretization.quadrature
        rows = global_index[quadrature.cell] * n_gauss + np.arange(len(quadrature.cell)) % n_gauss
        return quadrature, rows

    def _grouped_quadrature(self, part_id: int):
        """This rank's Gauss points of a coarse-trace part, and each point's group and offset.

        A group (:func:`~parefg.discretization.coarse_trace.trace_groups`, numbered on the
        whole part, as every rank holds the segments) belongs to the owner of its lowest
        segment, so its projection is local and does not depend on the partition.
        """
        cloud = self.cloud
        on_part = np.flatnonzero(cloud.segment_part == part_id)
        group, offset = coarse_trace.trace_groups(cloud.coords, cloud.segments, on_part)
        first = np.full(group.max() + 1 if len(group) else 0, len(cloud.segments))
        np.minimum.at(first, group, on_part)
        owner = self.partition.segment_owner[first[group]]
        mine = owner == self.comm.rank
        quadrature = segment_quadrature(
            cloud.coords,
            cloud.segments,
            self.scene.discretization.quadrature,
            segment_ids=on_part[mine],
        )
        n_gauss = self.scene.discretization.quadrature
        return quadrature, np.repeat(group[mine], n_gauss), np.repeat(offset[mine], n_gauss)

    def _boundaries(self):
        """Point sets of every boundary condition; D, its parts and the Gamma_C pattern."""
        scene, cloud, n = self.scene, self.cloud, self.n_nodes
        boundary, parts, contact_parts = {}, {}, []
        dirichlet_local = sp.csr_matrix((2 * n, 2 * n))
        for name, bc in scene.boundaries.items():
            part_id = cloud.part_names.index(name)
            if bc.kind == BoundaryKind.CONTACT:
                contact_parts.append(part_id)
                continue
            method = DIRICHLET_METHODS[bc.method] if bc.kind == BoundaryKind.DIRICHLET else None
            groups = None
            if method is not None and method.coarse:
                quadrature, *groups = self._grouped_quadrature(part_id)
            else:
                quadrature, _ = self._boundary_quadrature([part_id])
            consistent = method is not None and method.consistent
            shape = self._shape(quadrature.points, gradients=consistent)
            with phase(self.timings, "assembly"):
                boundary[name] = self._point_set(quadrature, shape)
            if method is not None:
                parts[name], local = self._dirichlet_part(method, bc, quadrature, shape, groups)
                dirichlet_local = dirichlet_local + local
        contact, pattern = None, sp.csr_matrix((2 * n, 2 * n))
        if contact_parts:
            quadrature, rows = self._boundary_quadrature(contact_parts)
            on_contact = np.isin(cloud.segment_part, contact_parts)  # every rank's segments
            self.n_contact = (
                int(np.count_nonzero(on_contact)) * self.scene.discretization.quadrature
            )
            nitsche_parts = self._nitsche_contact_parts()
            shape = self._shape(quadrature.points, gradients=bool(nitsche_parts))
            part_of_point = cloud.segment_part[quadrature.cell]
            extra = {}
            if nitsche_parts:
                extra = self._nitsche_contact(quadrature, shape, part_of_point, nitsche_parts)
                dirichlet_local = dirichlet_local - extra.pop("nitsche_matrix")
            with phase(self.timings, "assembly"):
                contact = self._point_set(quadrature, shape, part=part_of_point, rows=rows, **extra)
                coupling = Coupling.of(shape, n, quadrature.cell)
                pattern = coupling.interleaved(np.zeros((len(coupling.indices), 2, 2)))
        return boundary, parts, contact, dirichlet_local, pattern

    def _nitsche_contact_parts(self) -> list[int]:
        """Part ids of the contact parts imposed by Nitsche's method."""
        cloud, scene = self.cloud, self.scene
        return [
            cloud.part_names.index(name)
            for name, bc in scene.boundaries.items()
            if bc.kind == BoundaryKind.CONTACT and bc.method == "nitsche"
        ]

    def _nitsche_contact(self, quadrature, shape, part_of_point, nitsche_parts) -> dict:
        """sigma_nu(u_h) at the Gamma_C points, gamma, and N = T_nu^T W gamma^-1 T_nu.

        Chouly & Hild's symmetric Nitsche contact (parefg.mechanics.contact) is the
        penalty law with alpha_C = gamma on u_nu - sigma_nu / gamma, plus -N in the
        stiffness.  gamma is the part's safety times the coercivity bound of each segment
        (the Dirichlet parts' bound, shared with them where a cell has both): then
        a(v, v) - ||sigma_nu(v)||^2 / gamma >= (1 - 1 / (2 safety)) a(v, v).  Points of
        penalty contact parts get zero traction rows and gamma = alpha_C.
        """
        scene, n = self.scene, self.n_nodes
        lam, mu = scene.material.lam, scene.material.mu
        with phase(self.timings, "assembly"):  # the trace-inverse estimate
            segments = np.unique(quadrature.cell)
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
            if bc.kind == BoundaryKind.CONTACT and bc.method == "nitsche":
                safety[self.cloud.part_names.index(name)] = bc.safety
        # points are grouped by segment, in the order of np.unique(cell)
        segment_of_point = np.searchsorted(segments, quadrature.cell)
        nitsche = np.isin(part_of_point, nitsche_parts)
        gamma = np.where(
            nitsche,
            safety[part_of_point] * per_segment[segment_of_point],
            scene.penalty.alpha_contact,
        )
        with phase(self.timings, "assembly"):
            assert quadrature.normals is not None
            traction = traction_operator(shape, quadrature.normals, n, lam, mu)
            normals = quadrature.normals * nitsche[:, None]  # zero rows off Nitsche parts
            rotate = sp.csr_matrix(
                (
                    normals.ravel(),
                    (np.repeat(np.arange(len(normals)), 2), np.arange(2 * len(normals))),
                ),
                shape=(len(normals), 2 * len(normals)),
            )
            normal_traction = (rotate @ traction).tocsr()  # (n_c, 2 n) sigma_nu rows
            scale = sp.diags(quadrature.weights / gamma)
            matrix = (normal_traction.T @ scale @ normal_traction).tocsr()
            # PETSc, as the point set's value operator: no scipy twin is kept
            normal_traction = petsc_matrix(self.comm, normal_traction, self.n_dofs_local, 2 * n)
        return {"normal_traction": normal_traction, "gamma": gamma, "nitsche_matrix": matrix}

    def _dirichlet_part(self, method, bc, quadrature: Quadrature, shape: ShapeValues, groups):
        """One Dirichlet part by ``method``, and its local contributions to D.

        beta is alpha_D for the penalty, the part's safety times the coercivity bound of
        each segment (:func:`~parefg.discretization.trace_inverse.nitsche_beta`) for Nitsche,
        the largest of its group's for the coarse trace (``groups`` = (group, offset) of
        each point, else None): ||P sigma(v) n|| <= ||sigma(v) n|| on a group, so the
        bound holds for the projected form.
        """
        scene, n = self.scene, self.n_nodes
        if method.consistent:
            with phase(self.timings, "assembly"):  # the trace-inverse estimate
                per_segment = bc.safety * nitsche_beta(
                    self.mls,
                    self.cloud,
                    self._nitsche_segments(),
                    np.unique(quadrature.cell),
                    scene.discretization.quadrature,
                    scene.material.lam,
                    scene.material.mu,
                    edge_values=(quadrature.points, shape),
                )
            beta = np.repeat(
                per_segment, scene.discretization.quadrature
            )  # points are grouped by segment
        else:
            beta = np.full(len(quadrature.weights), scene.penalty.alpha_dirichlet)
        projection = None
        if groups is not None:
            group, offset = groups
            largest = np.zeros(group.max() + 1 if len(group) else 0)
            np.maximum.at(largest, group, beta)
            beta = largest[group]
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
                load=petsc_matrix(self.comm, load, self.n_dofs_local, 2 * n),
                traction=None
                if traction is None
                else petsc_matrix(self.comm, traction, self.n_dofs_local, 2 * n),
                projection=projection,
            )
        return part, local

    def _nitsche_segments(self) -> np.ndarray:
        """Every segment (all ranks) of a part imposed by Nitsche's method (Dirichlet, contact)."""
        cloud, names = self.cloud, []
        for name, bc in self.scene.boundaries.items():
            if bc.kind == BoundaryKind.DIRICHLET and DIRICHLET_METHODS[bc.method].consistent:
                names.append(cloud.part_names.index(name))
            if bc.kind == BoundaryKind.CONTACT and bc.method == "nitsche":
                names.append(cloud.part_names.index(name))
        return np.flatnonzero(np.isin(cloud.segment_part, names))
