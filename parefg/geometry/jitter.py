"""Jittered node clouds: seeded, fold-free perturbation of interior nodes.

``[discretization] jitter`` and ``seed`` of a scene move every interior node of
the gmsh cloud (:func:`parefg.geometry.gmsh_mesh.build_node_cloud`) by a random offset of
at most ``jitter`` times its local spacing, redrawing the nodes of any folded
cell, so that EFG can be tried on irregular clouds.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from parefg.errors import InputError
from parefg.geometry.cloud import NodeCloud, node_spacing

MAX_JITTER = 0.45  # fraction of the local spacing c_I
JITTER_ROUNDS = 20  # redraws of the nodes of folded cells; the last one restores them


def jitter_cloud(cloud: NodeCloud, jitter: float, seed: int = 0) -> NodeCloud:
    """The cloud with every interior node moved by a seeded random offset (not collective).

    x_I <- x_I + jitter c_I r_I with r_I uniform in [-1, 1]^2, drawn from
    ``numpy.random.default_rng(seed)`` for all nodes in cloud order; c_I is the
    local spacing (= h on a uniform grid), recomputed after the move.  Boundary
    nodes (ends of boundary segments) stay, so the domain, its parts and its
    area are unchanged.  Offsets of up to 0.45 h can fold a cell (two
    neighbours each moving 0.45 h across their common edge), so the nodes of
    folded cells draw again, each round with offsets scaled down by
    1 - round / JITTER_ROUNDS, until no cell folds: the result stays
    deterministic and every offset stays within jitter c_I.

    Raises
    ------
    InputError
        ``jitter`` outside [0, MAX_JITTER], or a cell still folded after
        JITTER_ROUNDS (a triangle, or a quadrilateral corner where the
        bilinear map's Jacobian, the corner's cross product, is <= 0).
    """
    if not 0.0 <= jitter <= MAX_JITTER:
        raise InputError(f"discretization.jitter = {jitter}: must be in 0..{MAX_JITTER}")
    if jitter == 0.0:
        return cloud
    rng = np.random.default_rng(seed)
    movable = np.ones(cloud.n_nodes, dtype=bool)
    movable[np.unique(cloud.segments)] = False
    step = jitter * cloud.spacing[:, None] * movable[:, None]  # (n_nodes, 1): 0 on the boundary
    coords = cloud.coords + step * rng.uniform(-1.0, 1.0, size=cloud.coords.shape)  # (N, d)
    for attempt in range(1, JITTER_ROUNDS + 1):
        folded = _folded_cells(coords, cloud.quads, cloud.triangles)
        if not len(folded):
            break
        # Redraw only the nodes of folded cells, with shrinking offsets (0 in the last round).
        redraw = np.unique(np.concatenate(folded))
        scale = 1.0 - attempt / JITTER_ROUNDS
        offsets = rng.uniform(-1.0, 1.0, size=(len(redraw), cloud.dim))  # (n_redraw, d)
        coords[redraw] = cloud.coords[redraw] + scale * step[redraw] * offsets
    folded = _folded_cells(coords, cloud.quads, cloud.triangles)
    if len(folded):
        raise InputError(
            f"discretization.jitter = {jitter} (seed {seed}) folds {len(folded)} mesh cell(s), "
            f"first near {np.round(coords[folded[0]].mean(axis=0), 6).tolist()}: "
            "use a smaller discretization.jitter or a finer, more regular mesh"
        )
    spacing = node_spacing(coords, cloud.quads, cloud.triangles)
    return dataclasses.replace(cloud, coords=coords, spacing=spacing)


def _folded_cells(coords, quads, triangles) -> list[np.ndarray]:
    """Corner lists of the cells with a non-positive corner cross product."""
    folded = []
    for cells in (quads, triangles):
        corners = coords[cells]  # (n_cells, n_corners, 2)
        forward = np.roll(corners, -1, axis=1) - corners
        backward = np.roll(corners, 1, axis=1) - corners
        cross = forward[..., 0] * backward[..., 1] - forward[..., 1] * backward[..., 0]
        folded.extend(cells[np.any(cross <= 0, axis=1)])
    return folded
