"""Time integration: the schemes (:mod:`.schemes`), the per-step solvers (SNES with the
exact line search, or one linear solve; :mod:`.step_solver`) and the simulation that
advances and checks the state step by step (:mod:`.simulation`).
"""
