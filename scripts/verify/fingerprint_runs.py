"""Fingerprint the results of the built-in scenes, to prove a refactoring changed nothing.

Runs square, z, impact and stick on one rank (each in a fresh temporary directory), and
records the SHA-256 of every dataset of result.h5 and the errors of summary.json.  With
``--compare FILE`` it compares against a fingerprint written earlier and exits 1 on any
difference, naming it.

    python scripts/verify/fingerprint_runs.py --write before.json
    python scripts/verify/fingerprint_runs.py --compare before.json
"""

import argparse
import hashlib
import json
import pathlib
import subprocess
import sys
import tempfile

import h5py
import numpy as np

SCENES = ("square", "z", "impact", "stick")
PAREFG = pathlib.Path(sys.executable).with_name("parefg")


def dataset_digests(path):
    """SHA-256 of every dataset in an HDF5 file, keyed by its path."""
    digests = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            data = np.ascontiguousarray(obj[()])
            digests[name] = hashlib.sha256(data.tobytes()).hexdigest()

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return digests


def fingerprint(scene):
    """Run one scene and return its result digests and summary errors."""
    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / scene
        subprocess.run([str(PAREFG), "run", scene, "--out", str(out), "--quiet"], check=True)
        summary = json.loads((out / "summary.json").read_text())
        return {"errors": summary.get("errors"), "datasets": dataset_digests(out / "result.h5")}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", type=pathlib.Path)
    group.add_argument("--compare", type=pathlib.Path)
    args = parser.parse_args()
    current = {scene: fingerprint(scene) for scene in SCENES}
    if args.write:
        args.write.write_text(json.dumps(current, indent=1, sort_keys=True))
        print(f"wrote {args.write}")
        return 0
    before = json.loads(args.compare.read_text())
    differences = [
        f"{scene}: {kind} {key}"
        for scene in SCENES
        for kind in ("errors", "datasets")
        for key in sorted(set(before[scene][kind] or {}) | set(current[scene][kind] or {}))
        if (before[scene][kind] or {}).get(key) != (current[scene][kind] or {}).get(key)
    ]
    for line in differences:
        print("differs:", line)
    counts = sum(len(current[s]["datasets"]) for s in SCENES)
    print(f"{len(SCENES)} scenes, {counts} datasets: {len(differences)} differences")
    return 1 if differences else 0


if __name__ == "__main__":
    sys.exit(main())
