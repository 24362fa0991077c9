"""Domains and node clouds: the built-in shapes and checked .geo files meshed by gmsh
(:mod:`.domains`, :mod:`.geo`), node jitter and the partition of nodes across ranks.
"""
