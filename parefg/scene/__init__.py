"""Scenes: the TOML schema (:mod:`.schema`), loading and derived data (:mod:`.loader`),
expressions and their symbolic checks (:mod:`.expressions`, :mod:`.symbolic`,
:mod:`.checks`), and the built-in scenes (``builtin/*.toml``).
"""
