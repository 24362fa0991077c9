"""Scenes: reading a TOML table key by key (:mod:`.table`), the schema of every section
(:mod:`.schema`, reading the registries of the layers below), loading and the
:class:`~.sections.Scene` of one frozen dataclass per section (:mod:`.loader`,
:mod:`.sections`), scene data as vectorized fields and boundary
conditions (:mod:`.fields`), data derived from ``[exact]`` (:mod:`.manufactured`),
expressions and their symbolic checks (:mod:`.expressions`, :mod:`.symbolic`,
:mod:`.checks`), and the built-in scenes (``builtin/*.toml``).
"""
