"""Refactors change no outputs: record the outputs of a fixed set of commands, and compare
two records.

    .venv/bin/python scripts/compare_outputs.py record --out /tmp/outputs-before [--only NAME ...]
    .venv/bin/python scripts/compare_outputs.py compare /tmp/outputs-before /tmp/outputs-after

`record` runs each command of CASES (`python -m app.cli` in this script's checkout, so a
second worktree records its own code; one BLAS thread; one after the other) into OUT/NAME/ and writes OUT/manifest.json: per case, the SHA-256 of every output
file, with the timings taken out of JSON files (any key containing "time", "timing" or "_ms",
and "wall_s") since they differ between any two runs. `compare` prints the cases whose files
differ and exits 1 if any do.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"

CASES: dict[str, list[str]] = {}
for scene in ("room", "corridor", "boxes"):
    for mode in ("stereo", "vio"):
        for variant in ("P-wo", "PL-w"):
            CASES[f"{scene}-{mode}-{variant}"] = ["run", "--scene", scene, "--mode", mode, "--variant", variant]
CASES["mh01-slice-PL-w"] = ["run", "--dataset", str(SHARED / "euroc_mh01_slice"), "--variant", "PL-w"]
CASES["sim-b"] = ["sim", "--sequence", "b", "--runs", "3"]  # the Monte-Carlo study (backend.eval.montecarlo)
CASES["mc-b-PL-w"] = ["run", "--scene", "mc-b", "--variant", "PL-w", "--keyframes", "60"]  # the Monte-Carlo engine (SimEngine)


def _strip_timings(value: object) -> object:
    if isinstance(value, dict):
        return {k: _strip_timings(v) for k, v in value.items() if not ("time" in k or "timing" in k or "_ms" in k or k == "wall_s")}
    if isinstance(value, list):
        return [_strip_timings(v) for v in value]
    return value


def digest(path: pathlib.Path) -> str:
    data = path.read_bytes()
    if path.suffix == ".json":
        data = json.dumps(_strip_timings(json.loads(data)), sort_keys=True).encode()
    return hashlib.sha256(data).hexdigest()


def record(out: pathlib.Path, only: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    manifest_path = out / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    for name, argv in CASES.items():
        if only and name not in only:
            continue
        if name.startswith("mh01") and not SHARED.exists():
            print(f"{name}: skipped ({SHARED} is missing)", flush=True)
            continue
        folder = out / name
        folder.mkdir(exist_ok=True)
        extra = ["--json", str(folder / "sim.json")] if argv[0] == "sim" else ["--out", str(folder)]
        t0 = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "app.cli", *argv, *extra], cwd=ROOT, env=env, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise SystemExit(f"{name}: exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1:]}")
        files = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix in (".txt", ".json", ".ply"))
        manifest[name] = {"argv": argv, "files": {str(p.relative_to(folder)): digest(p) for p in files}}
        manifest_path.write_text(json.dumps(manifest, indent=1, sort_keys=True))
        print(f"{name}: {len(files)} files, {time.monotonic() - t0:.0f} s", flush=True)


def compare(a: pathlib.Path, b: pathlib.Path) -> int:
    left = json.loads((a / "manifest.json").read_text())
    right = json.loads((b / "manifest.json").read_text())
    differ = 0
    for name in sorted(set(left) | set(right)):
        if name not in left or name not in right:
            print(f"{name}: only in {'the first' if name in left else 'the second'} record")
            differ += 1
            continue
        files_a, files_b = left[name]["files"], right[name]["files"]
        changed = sorted(f for f in set(files_a) | set(files_b) if files_a.get(f) != files_b.get(f))
        print(f"{name}: {'identical' if not changed else 'DIFFERS: ' + ', '.join(changed)} ({len(files_a)} files)")
        differ += bool(changed)
    print(f"{len(set(left) | set(right)) - differ} cases identical, {differ} differ")
    return 1 if differ else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("record")
    r.add_argument("--out", type=pathlib.Path, required=True)
    r.add_argument("--only", nargs="*", default=[])
    c = sub.add_parser("compare")
    c.add_argument("a", type=pathlib.Path)
    c.add_argument("b", type=pathlib.Path)
    args = parser.parse_args()
    if args.what == "record":
        record(args.out, args.only)
    else:
        sys.exit(compare(args.a, args.b))


if __name__ == "__main__":
    main()
