"""``python -m qmdf``: compose the config with Hydra, validate it, run the pipeline, report.

python -m qmdf                                  # the default pipeline on the embedded teacup
python -m qmdf +experiment=sparse_teacup        # an experiment overlay
python -m qmdf input.path=scan.ply              # your own mesh or point cloud
python -m qmdf -m sample.n_points=5000,20000    # a sweep (add hydra/launcher=joblib for parallel jobs)
"""

from __future__ import annotations

import logging
import os
import re
import signal
import sys
from pathlib import Path

from qmdf.rundir import ENV_VAR, conf_dir, new_run_name

log = logging.getLogger("qmdf")
SUSPECT_EXIT_CODE = 3  # a run that finished but whose verdict is suspect, under pipeline.strict


def summary_line(result) -> str:
    m = result.manifest
    parts = [f"{s['name']} {s['status']} {s['seconds']:.2f}s" for s in m["stages"]]
    line = f"qmdf {m['status']}" + (f" (quality: {m['quality']})" if m.get("quality") else "") + ": " + ", ".join(parts)
    if "metrics" in result.artifacts:
        mm = result.load("metrics")
        line += f" | CD {mm['chamfer']:.3e} HD {mm['hausdorff']:.3e} chi {mm['chi']}"
    line += f" -> {result.run_dir}"
    if m["unavailable_stages"]:
        line += f" (not available in this version: {', '.join(m['unavailable_stages'])})"
    return line


def task(cfg) -> dict:
    """One Hydra job: one run directory, one pipeline."""
    from hydra.core.hydra_config import HydraConfig

    from qmdf.artifacts import write_json
    from qmdf.errors import QmdfError
    from qmdf.pipeline import Pipeline
    from qmdf.report import report_finished_run

    hc = HydraConfig.get()
    run_dir = Path(hc.runtime.output_dir)
    received = []

    def on_term(signum, frame):  # a scheduler's SIGTERM ends the run as Ctrl-C does, with its own exit code
        received.append(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)
    try:
        result = Pipeline(cfg, run_dir, base_dir=Path(hc.runtime.cwd)).run()
        report_finished_run(run_dir, cfg)
    except KeyboardInterrupt:
        code = 128 + (received[-1] if received else signal.SIGINT)
        log.error(
            "interrupted (%s); the run is marked interrupted in %s",
            signal.Signals(code - 128).name,
            run_dir / "manifest.json",
        )
        sys.stderr.flush()
        raise SystemExit(code) from None
    except QmdfError as exc:
        if not (run_dir / "manifest.json").exists():  # the run never started: say so on disk too
            write_json(run_dir / "manifest.json", {"status": "failed", "error": str(exc), "stages": []})
        log.error("%s", exc)
        sys.stderr.flush()
        raise SystemExit(exc.exit_code) from None
    line = summary_line(result)
    logging.getLogger("qmdf.summary").info("%s", line)
    print(line, flush=True)
    if result.manifest.get("quality") == "suspect":
        reasons = "; ".join(result.manifest.get("quality_reasons") or [])
        log.warning("quality: suspect: the result contradicts its input (%s); see report.html", reasons)
        if cfg.pipeline.get("strict"):
            log.error("pipeline.strict=true: a suspect result ends the run with exit code 3")
            sys.stderr.flush()
            raise SystemExit(SUSPECT_EXIT_CODE)
    return result.manifest


#: what Hydra's override grammar takes unquoted in a value (a path with a space, a parenthesis or a non-ASCII
#: letter is a grammar error unless quoted)
_PLAIN_VALUE = re.compile(r"[A-Za-z0-9_./\\:~+-]*")
_PATH_KEYS = ("input.path=", "cache.dir=")


def quote_paths(argv: list[str]) -> list[str]:
    """``input.path=my scan (1).ply`` as Hydra needs it: the value quoted. The shell has already removed the
    user's own quotes, so a path with spaces, parentheses or accents would otherwise stop at Hydra's grammar."""
    out = []
    for arg in argv:
        key = next((k for k in _PATH_KEYS if arg.startswith(k)), None)
        value = arg[len(key) :] if key else ""
        if key and value and value[0] not in "'\"" and not _PLAIN_VALUE.fullmatch(value):
            arg = key + "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"
        out.append(arg)
    return out


def main() -> None:
    import hydra

    from qmdf.config import register_configs

    if any(a in ("--help", "-h", "--help-expert") for a in sys.argv[1:]):
        from qmdf.cli_help import help_text

        sys.stdout.write(help_text(conf_dir(), expert="--help-expert" in sys.argv[1:]))
        raise SystemExit(0)
    sys.argv[1:] = quote_paths(sys.argv[1:])
    # One fresh name per invocation: the run (or the sweep) directory. Jobs of a multirun share it.
    os.environ[ENV_VAR] = new_run_name()
    register_configs()
    hydra.main(config_path=str(conf_dir()), config_name="config", version_base="1.3")(task)()


if __name__ == "__main__":
    main()
