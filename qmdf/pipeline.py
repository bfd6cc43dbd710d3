"""Runs the configured list of stages over one run directory.

Before anything runs, the plan is checked: every stage name is known, and every input a stage reads is made
by an earlier stage (the latest producer of a name wins, so e.g. ``feature_retrain`` can re-make ``field``
and later stages read the new one while the first result stays in its own folder).

Each stage's result is cached by content: its key hashes the stage's name and version, its config section,
the other config sections it depends on, and the content digests of its input artifacts. A re-run, or a
multirun job that only changes a downstream stage, copies the upstream results from ``cache.dir`` instead of
recomputing them. Parallel jobs computing the same key wait on a file lock rather than duplicate the work.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import hashlib
import json
import logging
import os
import shutil
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from omegaconf import DictConfig, OmegaConf

from qmdf import config as config_mod
from qmdf import __version__
from qmdf.artifacts import ArtifactKind, file_digest, kind_named, write_json
from qmdf.errors import Interrupted, PipelineError, QmdfError
from qmdf.registry import STAGES
from qmdf.stage import RunSettings, Stage, StageContext

log = logging.getLogger("qmdf.pipeline")


@dataclass
class Step:
    index: int
    name: str
    stage: Stage
    cfg: Any

    @property
    def dirname(self) -> str:
        return f"{self.index:02d}_{self.name}"


@dataclass
class Plan:
    steps: list[Step]
    unavailable: list[str]  # configured built-in stages that this version does not have
    not_run: list[str]  # configured stages after the first unavailable one, or after stop_after


def make_plan(cfg: DictConfig | dict) -> Plan:
    names = list(cfg["pipeline"]["stages"])
    stop_after = cfg["pipeline"].get("stop_after")
    steps: list[Step] = []
    unavailable = [n for n in names if n not in STAGES]
    for i, name in enumerate(names):
        if name not in STAGES:
            break
        entry = STAGES.get(name)
        steps.append(Step(i, name, entry.obj(), config_mod.typed_section(cfg, name)))
        if name == stop_after:
            break
    not_run = names[len(steps) :]
    check_wiring(steps)
    return Plan(steps, unavailable, not_run)


def check_wiring(steps: list[Step]) -> None:
    """Raise PipelineError listing every input that no earlier stage makes, or makes with another kind."""
    made: dict[str, tuple[ArtifactKind, str]] = {}
    problems = []
    for step in steps:
        st = step.stage
        for name, kind in st.inputs.items():
            if name not in made:
                makers = [e.name for e in STAGES.entries() if name in e.obj.outputs or name in e.obj.optional_outputs]
                hint = f" (made by: {', '.join(makers)})" if makers else ""
                problems.append(
                    f"stage '{step.name}' (#{step.index}) reads '{name}', which no earlier stage makes{hint}"
                )
            elif made[name][0] is not kind:
                problems.append(
                    f"stage '{step.name}' reads '{name}' as {kind.name}, "
                    f"but '{made[name][1]}' makes it as {made[name][0].name}"
                )
        for name, kind in {**st.outputs, **st.optional_outputs}.items():
            made[name] = (kind, step.name)
    if problems:
        raise PipelineError("the pipeline's wiring is broken:\n" + "\n".join(f"  - {p}" for p in problems))


@dataclass
class ArtifactRecord:
    name: str
    kind: str
    path: Path  # absolute
    digest: str
    producer: str


@dataclass
class RunResult:
    run_dir: Path
    manifest: dict
    artifacts: dict[str, ArtifactRecord] = field(default_factory=dict)

    @classmethod
    def open(cls, run_dir: Path | str) -> "RunResult":
        """A finished run from its folder: its manifest and the artifacts of its stages, the latest of each name
        (as a later stage reads them)."""
        run_dir = Path(run_dir)
        path = run_dir / "manifest.json"
        if not path.is_file():
            raise PipelineError(f"{run_dir} has no manifest.json: not a run folder")
        manifest = json.loads(path.read_text())
        artifacts = {
            name: ArtifactRecord(name, a["kind"], run_dir / a["path"], a.get("sha256", ""), st["name"])
            for st in manifest.get("stages", [])
            for name, a in (st.get("artifacts") or {}).items()
        }
        return cls(run_dir, manifest, artifacts)

    @property
    def complete(self) -> bool:
        return self.manifest["status"] == "complete"

    def _record(self, name: str) -> ArtifactRecord:
        if name not in self.artifacts:
            raise PipelineError(f"this run made no artifact '{name}' (it made: {', '.join(self.artifacts)})")
        return self.artifacts[name]

    def path(self, name: str) -> Path:
        return self._record(name).path

    def load(self, name: str) -> Any:
        rec = self._record(name)
        if rec.producer in STAGES:
            producer = STAGES.get(rec.producer).obj
            kind = {**producer.outputs, **producer.optional_outputs}[name]
        else:  # an opened run, its stages not imported: the built-in kind by the name the manifest gives
            kind = kind_named(rec.kind)
            if kind is None:
                raise PipelineError(
                    f"artifact '{name}' is of kind '{rec.kind}', which only its stage "
                    f"'{rec.producer}' can read: import it first"
                )
        return kind.load(rec.path) if kind.load else rec.path


def _stable_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def _section(cfg: DictConfig | dict, key: str) -> Any:
    value = cfg.get(key)
    return OmegaConf.to_container(value, resolve=True) if isinstance(value, DictConfig) else value


def _remove_if_empty(folder: Path) -> None:
    """Remove ``folder`` if it is empty (a failed stage's scratch), and the run's ``.work`` if that empties it."""
    with contextlib.suppress(OSError):
        folder.rmdir()
        if folder.parent.name == ".work":
            folder.parent.rmdir()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def abandoned_run(run_dir: Path) -> dict | None:
    """A manifest left 'running' by a process of this host that is gone (killed, SIGKILL, power loss): say so,
    remove its half-written stage folders, and return what it was (``status: abandoned``) for the new manifest."""
    path = run_dir / "manifest.json"
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if (
        old.get("status") != "running"
        or old.get("host") != socket.gethostname()
        or not old.get("pid")
        or _alive(int(old["pid"]))
    ):
        return None
    for partial in run_dir.glob(".*.partial"):
        shutil.rmtree(partial, ignore_errors=True)
    log.warning(
        "the previous run in %s was abandoned (process %s, started %s, is gone); its partial stage folders are removed",
        run_dir,
        old["pid"],
        old.get("started"),
    )
    return {
        "status": "abandoned",
        "pid": old["pid"],
        "started": old.get("started"),
        "stages_done": [s["name"] for s in old.get("stages", [])],
    }


class Pipeline:
    def __init__(self, cfg: DictConfig, run_dir: Path, base_dir: Path):
        self.base_dir = Path(base_dir).resolve()
        config_mod.check(cfg, self.base_dir)
        self.cfg = cfg
        self.run_dir = Path(run_dir).resolve()
        root = config_mod.typed_root(cfg)
        self.settings = RunSettings(root.seed, root.input, self.base_dir, self.run_dir)
        self.cache = root.cache
        cache_dir = Path(root.cache.dir).expanduser()
        self.cache_dir = cache_dir if cache_dir.is_absolute() else self.base_dir / cache_dir
        self.plan = make_plan(cfg)

    # -- manifest ---------------------------------------------------------------------------
    def _write_manifest(self, manifest: dict) -> None:
        write_json(self.run_dir / "manifest.json", manifest)

    # -- cache keys ------------------------------------------------------------------------
    def _hashed_section(self, key: str) -> Any:
        """A config section as it enters a cache key: a stage's own through its ``cache_config``."""
        value = _section(self.cfg, key)
        if isinstance(value, dict) and key in STAGES:
            return STAGES.get(key).obj.cache_config(value)
        return value

    def stage_key(self, step: Step, inputs: dict[str, ArtifactRecord], ctx: StageContext) -> str:
        st = step.stage
        material = {
            "stage": step.name,
            "class": f"{type(st).__module__}.{type(st).__qualname__}",
            "version": st.version,
            "qmdf": __version__,  # an upgrade never serves results of older code
            "config": self._hashed_section(step.name),
            "deps": {k: self._hashed_section(k) for k in st.config_deps},
            "inputs": {k: v.digest for k, v in sorted(inputs.items())},
            "fingerprint": st.fingerprint(ctx),
        }
        return hashlib.sha256(_stable_json(material).encode()).hexdigest()

    def _forced(self, name: str) -> bool:
        return "all" in self.cache.force or name in self.cache.force

    # -- running -------------------------------------------------------------------------------
    def run(self) -> RunResult:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        previous = abandoned_run(self.run_dir)
        OmegaConf.save(self.cfg, self.run_dir / "config.yaml", resolve=True)
        plan = self.plan
        manifest: dict[str, Any] = {
            "qmdf_version": __version__,
            "run_dir": str(self.run_dir),
            "started": dt.datetime.now().isoformat(timespec="microseconds"),
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "status": "running",
            "pipeline": list(self.cfg["pipeline"]["stages"]),
            "unavailable_stages": plan.unavailable,
            "not_run": plan.not_run,
            "stages": [],
        }
        if previous:
            manifest["previous"] = previous
        if plan.unavailable:
            log.warning(
                "stages not available in qmdf %s: %s. Running only: %s",
                __version__,
                ", ".join(plan.unavailable),
                ", ".join(s.name for s in plan.steps) or "nothing",
            )
        self._write_manifest(manifest)
        result = RunResult(self.run_dir, manifest)
        try:
            for step in plan.steps:
                record = self._run_step(step, result.artifacts)
                manifest["stages"].append(record)
                self._write_manifest(manifest)
        except BaseException as exc:
            manifest["status"] = "interrupted" if isinstance(exc, (Interrupted, KeyboardInterrupt)) else "failed"
            manifest["error"] = str(exc) if isinstance(exc, QmdfError) else f"{type(exc).__name__}: {exc}"
            manifest["finished"] = dt.datetime.now().isoformat(timespec="microseconds")
            self._write_manifest(manifest)
            raise
        manifest["status"] = "complete" if not plan.not_run else "partial"
        if "metrics" in result.artifacts:  # the run's verdict on itself (qmdf.verdict), beside its status
            found = result.load("metrics").get("verdict") or {}
            manifest["quality"], manifest["quality_reasons"] = found.get("quality", "unchecked"), found.get("reasons")
        manifest["finished"] = dt.datetime.now().isoformat(timespec="microseconds")
        self._write_manifest(manifest)
        return result

    def _run_step(self, step: Step, produced: dict[str, ArtifactRecord]) -> dict:
        st = step.stage
        inputs: dict[str, ArtifactRecord] = {}
        for name in list(st.inputs) + list(st.optional_inputs):
            if name in produced:
                inputs[name] = produced[name]
            elif name in st.inputs:
                raise PipelineError(f"stage '{step.name}' needs '{name}', but its producer did not write it this run")
        final_dir = self.run_dir / step.dirname
        if final_dir.exists():
            shutil.rmtree(final_dir)
        ctx = StageContext(
            stage=st,
            cfg=step.cfg,
            settings=self.settings,
            stage_dir=final_dir,
            input_paths={k: v.path for k, v in inputs.items()},
            log=logging.getLogger(f"qmdf.stage.{step.name}"),
            sections={k: config_mod.typed_section(self.cfg, k) for k in st.config_deps if k in STAGES},
        )
        key = self.stage_key(step, inputs, ctx)
        entry = self.cache_dir / step.name / key
        ctx.work_dir = entry.with_name(f"{key}.work") if self.cache.enabled else self.run_dir / ".work" / step.dirname
        ctx.work_dir.mkdir(parents=True, exist_ok=True)
        t0, cpu0 = time.perf_counter(), time.process_time()
        status = "ran"
        use_cache = self.cache.enabled
        with self._locked(entry) if use_cache else contextlib.nullcontext():
            if use_cache and not self._forced(step.name) and (entry / "artifacts.json").exists():
                shutil.copytree(entry, final_dir, ignore=shutil.ignore_patterns("artifacts.json"))
                written = json.loads((entry / "artifacts.json").read_text())
                status = "cached"
                log.info("[%s] reused cached result %s", step.name, key[:12])
            else:
                log.info("[%s] running", step.name)
                try:
                    written = self._execute(step, ctx, final_dir)
                except BaseException:
                    _remove_if_empty(ctx.work_dir)  # a checkpoint to resume from stays; an empty folder does not
                    raise
                if use_cache:
                    self._store(entry, final_dir, written)
            shutil.rmtree(ctx.work_dir, ignore_errors=True)
        seconds = time.perf_counter() - t0
        record = {
            "index": step.index,
            "name": step.name,
            "status": status,
            "key": key,
            "seconds": round(seconds, 3),
            "cpu_seconds": round(time.process_time() - cpu0, 3),  # all threads
            "peak_rss_mb": peak_rss_mb(),
            "dir": step.dirname,
            "artifacts": {},
        }
        for name, rel in written.items():
            path = final_dir / rel
            kind = {**st.outputs, **st.optional_outputs}[name]
            digest = file_digest(path)
            produced[name] = ArtifactRecord(name, kind.name, path, digest, step.name)
            record["artifacts"][name] = {
                "path": f"{step.dirname}/{rel}",
                "kind": kind.name,
                "sha256": digest,
                "bytes": path.stat().st_size,
            }
        if (final_dir / "notes.json").exists():
            record["notes"] = json.loads((final_dir / "notes.json").read_text())
        if status == "ran":
            log.info("[%s] done in %.2f s", step.name, seconds)
        return record

    def _execute(self, step: Step, ctx: StageContext, final_dir: Path) -> dict[str, str]:
        """Run the stage in a scratch folder and move it into place only when it finished and wrote its outputs."""
        scratch = final_dir.with_name(f".{final_dir.name}.partial")
        if scratch.exists():
            shutil.rmtree(scratch)
        scratch.mkdir(parents=True)
        ctx.stage_dir, ctx.output_dir = scratch, final_dir
        try:
            step.stage.run(ctx)
            if ctx.notes:
                (scratch / "notes.json").write_text(json.dumps(ctx.notes, indent=2, default=str) + "\n")
            missing = [n for n in step.stage.outputs if n not in ctx.written or not ctx.written[n].exists()]
            if missing:
                raise PipelineError(f"stage '{step.name}' finished without writing: {', '.join(missing)}")
        except BaseException:
            shutil.rmtree(scratch, ignore_errors=True)
            raise
        os.replace(scratch, final_dir)
        ctx.stage_dir = final_dir
        release_freed_memory()
        return {name: path.name for name, path in ctx.written.items()}

    def _store(self, entry: Path, stage_dir: Path, written: dict[str, str]) -> None:
        tmp = entry.with_name(f".{entry.name}.tmp{os.getpid()}")
        if tmp.exists():
            shutil.rmtree(tmp)
        shutil.copytree(stage_dir, tmp)
        (tmp / "artifacts.json").write_text(json.dumps(written, indent=2))
        if entry.exists():
            shutil.rmtree(entry)  # a forced recomputation replaces the old entry
        os.replace(tmp, entry)

    @contextlib.contextmanager
    def _locked(self, entry: Path) -> Iterator[None]:
        entry.parent.mkdir(parents=True, exist_ok=True)
        with open(entry.with_name(entry.name + ".lock"), "w") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)


def release_freed_memory() -> None:
    """Hand what a finished stage freed back to the system: glibc keeps freed heap chunks for reuse, and the next
    stage's arrays, of other sizes, fragment around them, so every stage's peak stacked on the last one's."""
    import ctypes
    import gc

    gc.collect()
    try:  # the process's own symbols: no library search (find_library runs ldconfig in a subprocess each call)
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc (macOS, musl): nothing to trim
        pass


def peak_rss_mb() -> float | None:
    """This process's peak resident memory so far (Linux VmHWM: unlike ru_maxrss, it is not inherited from
    the process that started us), or None where /proc is not there."""
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        pass
    return None
