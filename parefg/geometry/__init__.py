"""Domains and node clouds, lowest module first: the node cloud and its mesh helpers
(:mod:`.cloud`), the polygon checks (:mod:`.polygon`), jittered clouds (:mod:`.jitter`),
the built-in domain shapes (:mod:`.shapes`, registry ``SHAPES``), checked .geo files
(:mod:`.geo`), gmsh meshing and the collective :func:`~.gmsh_mesh.build_node_cloud`
(:mod:`.gmsh_mesh`), the partition of nodes across ranks (:mod:`.partition`) and the
sending of each rank's part (:mod:`.distribute`), and a rectangle's grid and the Z's
patches made part by part on each rank (:mod:`.grid_parts`, :mod:`.patch_parts`).
"""
