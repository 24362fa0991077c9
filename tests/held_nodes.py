"""MLS over the nodes a rank holds, with neighbour lists in global node numbers.

A distributed discretization holds only its rank's nodes and their ghosts
(parefg.discretization.ghosts); the tests' references index matrices by global node,
so their shape functions come from :func:`global_mls`.
"""

import numpy as np

from parefg.discretization.mls import MLS


class GlobalMLS:
    """``MLS`` of a discretization's held nodes whose ``evaluate`` lists global nodes.

    Complete lists for the points of the rank (those in its evaluation box), as the
    discretization's own MLS.
    """

    def __init__(self, disc_or_cloud, settings, **options):
        cloud = getattr(disc_or_cloud, "cloud", disc_or_cloud)
        self.node_ids = cloud.global_ids()
        self.mls = MLS(cloud.coords, settings.support * cloud.spacing, settings.degree,
                       settings.weight, support_factor=settings.support, **options)  # fmt: skip

    def evaluate(self, points, gradients=True):
        shape = self.mls.evaluate(points, gradients=gradients)
        shape.neighbours = self.node_ids[shape.neighbours]
        return shape


def global_mls(disc_or_cloud, settings, **options) -> GlobalMLS:
    return GlobalMLS(disc_or_cloud, settings, **options)


def whole_array(node_ids, nodes: np.ndarray) -> np.ndarray:
    """Held positions -> global numbers (-1 kept)."""
    return np.where(nodes >= 0, node_ids[nodes], -1)
