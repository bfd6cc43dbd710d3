"""``python -m qmdf.bench faults``: the pipeline under faults, counted.

1. Interrupt and resume: N trainings (tiny settings, ``+debug=fast`` with more steps) each stopped by SIGINT,
   SIGTERM or SIGKILL in turn once a checkpoint exists, then run again with the same command: the exit status of
   the stopped run (130, 143, -9), the rerun's status, its step count, and the largest weight difference to an
   uninterrupted training (0 to round-off is the requirement).
2. Reader fuzzing: random bytes and damaged valid files of every input format (PLY ascii and binary) through
   ``load_geometry``: how many were read, refused with an input error (by class), or crashed (must be 0).
3. A multirun of M jobs on 2 joblib workers sharing one cache (the same seed, so every job wants the same
   entries at once): jobs complete, and every cache entry holds the files its manifest records, byte for byte.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

TRAIN = ["+debug=fast", "pipeline.stages=[sample,train]", "train.optim.steps=400", "train.trainer.checkpoint_every=25"]
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGKILL)


def _qmdf(args: list[str]) -> list[str]:
    return [sys.executable, "-m", "qmdf", *args]


def _weights(run_dir: Path) -> dict:
    import torch

    field = next(run_dir.glob("*_train/field.pt"))
    return torch.load(field, map_location="cpu", weights_only=True)["state_dict"]


def interrupt_trials(out: Path, trials: int, timeout: float = 600) -> list[dict]:
    ref_dir = out / "reference"
    subprocess.run(
        _qmdf([*TRAIN, f"hydra.run.dir={ref_dir}", f"cache.dir={out / 'cache_ref'}"]),
        check=True,
        capture_output=True,
        timeout=timeout,
    )
    reference = _weights(ref_dir)
    rows = []
    for i in range(trials):
        sig = SIGNALS[i % len(SIGNALS)]
        run_dir, cache = out / f"trial{i}", out / f"cache{i}"
        cmd = _qmdf([*TRAIN, f"hydra.run.dir={run_dir}", f"cache.dir={cache}", "seed=0"])
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + timeout
        while not list(cache.glob("train/*.work/last.ckpt")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(float(np.random.default_rng(i).uniform(0.0, 1.0)))  # somewhere after the first checkpoint
        proc.send_signal(sig)
        stopped = proc.wait(timeout=timeout)
        rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        manifest = json.loads((run_dir / "manifest.json").read_text())
        row = {
            "trial": i,
            "signal": signal.Signals(sig).name,
            "stopped_exit": stopped,
            "rerun_exit": rerun.returncode,
            "status": manifest.get("status"),
            "resumed": "resuming from" in rerun.stderr + rerun.stdout,
        }
        if rerun.returncode == 0:
            training = json.loads(next(run_dir.glob("*_train/training.json")).read_text())
            weights = _weights(run_dir)
            row["steps"] = training["steps"]
            row["max_weight_diff"] = float(max((weights[k] - reference[k]).abs().max() for k in reference))
        rows.append(row)
    return rows


def fuzz_readers(per_format: int, seed: int = 0) -> dict:
    import io

    import trimesh

    from qmdf.errors import InputError
    from qmdf.geometry.io import load_geometry

    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=1)
    valid = {".xyz": "\n".join(" ".join(f"{c:.5f}" for c in p) for p in mesh.vertices).encode()}
    buf = io.BytesIO()
    np.save(buf, np.asarray(mesh.vertices))
    valid[".npy"] = buf.getvalue()
    for ext in ("ply", "obj", "off", "stl"):
        data = mesh.export(file_type=ext, **({"encoding": "ascii"} if ext == "ply" else {}))
        valid["." + ext] = data if isinstance(data, bytes) else data.encode()
    valid[".ply binary"] = mesh.export(file_type="ply", encoding="binary")
    counts = {"read": 0, "refused": 0, "crashed": 0}
    crashes = []
    classes: dict[str, int] = {}
    work = Path(os.environ.get("TMPDIR", "/tmp")) / f"qmdf_fuzz_{os.getpid()}"
    work.mkdir(parents=True, exist_ok=True)
    for suffix, good in valid.items():
        for k in range(per_format):
            if k % 2:
                data = rng.bytes(int(rng.integers(1, 400)))
            else:
                data = bytearray(good)
                for _ in range(int(rng.integers(0, 6))):
                    data[int(rng.integers(len(data)))] = int(rng.integers(256))
                data = bytes(data[: max(1, int(rng.uniform(0.05, 1.0) * len(data)))])
            path = work / f"f{suffix.split()[0]}"
            path.write_bytes(data)
            try:
                load_geometry(path)
                counts["read"] += 1
            except InputError as exc:
                counts["refused"] += 1
                # the error's class: its words up to the first detail, the file's name taken out
                kind = re.sub(r"\d+", "N", " ".join(str(exc).replace(str(path), "FILE").split(":")[0].split()[:8]))
                classes[kind] = classes.get(kind, 0) + 1
            except Exception as exc:  # noqa: BLE001 - what the bench counts
                counts["crashed"] += 1
                crashes.append(f"{suffix}: {type(exc).__name__}: {exc}"[:200])
    return {
        **counts,
        "per_format": per_format,
        "formats": len(valid),
        "crashes": crashes[:10],
        "error_classes": dict(sorted(classes.items(), key=lambda kv: -kv[1])),
    }


def multirun_cache(out: Path, jobs: int, timeout: float = 3600) -> dict:
    from qmdf.artifacts import file_digest

    sweep, cache = out / "multirun", out / "cache_multirun"
    seeds = ",".join(["0"] * jobs)
    proc = subprocess.run(
        _qmdf(
            [
                "-m",
                "hydra/launcher=joblib",
                "hydra.launcher.n_jobs=2",
                f"seed={seeds}",
                "+debug=fast",
                f"hydra.sweep.dir={sweep}",
                f"cache.dir={cache}",
            ]
        ),
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    manifests = [json.loads(p.read_text()) for p in sweep.glob("*/manifest.json")]
    complete = sum(m.get("status") == "complete" for m in manifests)
    mismatched = 0
    for m in manifests:
        for st in m.get("stages", []):
            entry = cache / st["name"] / st["key"]
            for a in st["artifacts"].values():
                cached = entry / Path(a["path"]).name
                if not (entry / "artifacts.json").exists() or not cached.exists() or file_digest(cached) != a["sha256"]:
                    mismatched += 1
    leftovers = [p.name for p in cache.rglob("*") if p.name.endswith((".work", ".partial")) or ".tmp" in p.name]
    return {
        "jobs": jobs,
        "exit": proc.returncode,
        "complete": complete,
        "artifacts_not_matching_cache": mismatched,
        "leftover_scratch": len(leftovers),
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m qmdf.bench faults",
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--trials", type=int, default=9, help="interrupt/resume trials (signals in turn)")
    ap.add_argument("--fuzz", type=int, default=500, help="fuzzed files per input format")
    ap.add_argument("--jobs", type=int, default=100, help="jobs of the shared-cache multirun")
    ap.add_argument("--out", type=Path, default=Path("runs/bench/faults"))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    report: dict = {}
    if args.trials:
        report["interrupts"] = rows = interrupt_trials(args.out, args.trials)
        for r in rows:
            print(
                f"trial {r['trial']}: {r['signal']:<8} stopped with {r['stopped_exit']:>4}, rerun {r['rerun_exit']} "
                f"({r['status']}, resumed {r['resumed']}), steps {r.get('steps')}, "
                f"max weight difference to the uninterrupted field {r.get('max_weight_diff', float('nan')):.2e}"
            )
    if args.fuzz:
        report["fuzz"] = f = fuzz_readers(args.fuzz)
        print(
            f"fuzzed readers: {f['formats'] * f['per_format']} files: {f['read']} read, {f['refused']} refused with "
            f"one line, {f['crashed']} crashed"
            + "".join(f"\n  crash: {c}" for c in f["crashes"])
            + "".join(f"\n  {n:>5}  {k}" for k, n in f["error_classes"].items())
        )
    if args.jobs:
        report["multirun"] = m = multirun_cache(args.out, args.jobs)
        print(
            f"multirun: {m['jobs']} jobs on 2 workers, one cache: exit {m['exit']}, {m['complete']} complete, "
            f"{m['artifacts_not_matching_cache']} artifacts differing from their cache entry, "
            f"{m['leftover_scratch']} scratch folders left"
        )
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    ok = (
        all(r["rerun_exit"] == 0 and r.get("max_weight_diff", 1) < 1e-5 for r in report.get("interrupts", []))
        and report.get("fuzz", {}).get("crashed", 0) == 0
        and (
            not args.jobs
            or (report["multirun"]["complete"] == args.jobs and report["multirun"]["artifacts_not_matching_cache"] == 0)
        )
    )
    return 0 if ok else 1
