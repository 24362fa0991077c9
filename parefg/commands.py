"""Implementations of the CLI subcommands; each takes (comm, args) and returns an exit code."""

from __future__ import annotations

import platform

from parefg import __version__


def run(comm, args) -> int:
    from parefg.petsc_options import step_solver_options
    from parefg.run import run_scene
    from parefg.scene.loader import load_scene

    # --solver is solver.method given last: it wins over the scene and --set
    method = [] if args.solver is None else [f"solver.method={args.solver}"]
    scene = load_scene(args.scene, [*args.set, *method], step_solver_options())
    run_scene(
        comm,
        scene,
        out=args.out,
        quiet=args.quiet,
        fail_at_step=args.fail_at_step,
        checkpoint_every=args.checkpoint_every,
        restart=args.restart,
        max_memory=args.max_memory,
    )
    return 0


def sweep(comm, args) -> int:
    from parefg.sweep import run_sweep

    run_sweep(comm, args.scene, args.vary, args.set, args.out, args.max_memory)
    return 0


def scenes(comm, args) -> int:
    from parefg.scene.loader import builtin_scenes

    if comm.rank == 0:
        for name, description in builtin_scenes().items():
            print(f"{name:<12} {description}")
    return 0


def info(comm, args) -> int:
    import gmsh
    import h5py
    import mpi4py
    import numpy
    import petsc4py
    from mpi4py import MPI
    from petsc4py import PETSc

    from parefg.discretization import backends

    if comm.rank == 0:
        config = petsc4py.get_config()
        packages = [
            p
            for p in ("mumps", "hypre", "superlu_dist", "hdf5", "metis", "parmetis")
            if PETSc.Sys.hasExternalPackage(p)
        ]
        rows = [
            ("parefg", __version__),
            ("python", platform.python_version()),
            ("numpy", numpy.__version__),
            ("petsc", ".".join(map(str, PETSc.Sys.getVersion()))),
            ("petsc4py", petsc4py.__version__),
            ("PETSC_DIR", config.get("PETSC_DIR", "")),
            ("PETSc packages", ", ".join(packages)),
            ("mpi4py", mpi4py.__version__),
            ("MPI", MPI.Get_library_version().splitlines()[0]),
            ("ranks", str(comm.size)),
            ("h5py", f"{h5py.__version__} (mpi: {h5py.get_config().mpi})"),
            ("gmsh", gmsh.__version__),
            ("kernels", backends.describe()),
        ]
        for key, value in rows:
            print(f"{key:<16} {value}")
    return 0
