"""Domains and node clouds, lowest module first: the node cloud and its mesh helpers
(:mod:`.cloud`), the polygon checks (:mod:`.polygon`), jittered clouds (:mod:`.jitter`),
the built-in domain shapes (:mod:`.shapes`, registry ``SHAPES``), checked .geo files
(:mod:`.geo`), gmsh meshing and the collective :func:`~.gmsh_mesh.build_node_cloud`
(:mod:`.gmsh_mesh`), and the partition of nodes across ranks (:mod:`.partition`).
"""
