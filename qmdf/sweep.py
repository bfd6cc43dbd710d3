"""Collect a multirun's per-job results into one table: ``metrics.csv``, ``metrics.md`` and ``report.html`` (each
job linked to its own report) in the sweep dir.

Runs at the end of every multirun (a Hydra callback, see conf/config.yaml), and by hand:
``python -m qmdf.sweep runs/multirun/DATE/TIME``.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Any

SCALARS = ("chamfer", "hausdorff", "chi", "boundary_smoothness", "vertices", "faces")


def collect(sweep_dir: Path) -> list[dict[str, Any]]:
    rows = []
    for manifest_path in sorted(
        Path(sweep_dir).glob("*/manifest.json"), key=lambda p: (len(p.parent.name), p.parent.name)
    ):
        job = manifest_path.parent
        m = json.loads(manifest_path.read_text())
        overrides_file = job / ".hydra" / "overrides.yaml"
        overrides: list[str] = []
        if overrides_file.exists():
            overrides = [ln[2:].strip() for ln in overrides_file.read_text().splitlines() if ln.startswith("- ")]
        row: dict[str, Any] = {"job": job.name, "overrides": overrides, "status": m.get("status")}
        row["seconds"] = round(sum(s.get("seconds", 0) for s in m.get("stages", [])), 2)
        metrics_rel = next(
            (
                s["artifacts"]["metrics"]["path"]
                for s in reversed(m.get("stages", []))
                if "metrics" in s.get("artifacts", {})
            ),
            None,
        )
        if metrics_rel:
            metrics = json.loads((job / metrics_rel).read_text())
            row.update({k: metrics.get(k) for k in SCALARS})
        rows.append(row)
    # show only the overrides that differ between jobs: what the sweep varied
    common = set.intersection(*(set(r["overrides"]) for r in rows)) if rows else set()
    for r in rows:
        r["overrides"] = " ".join(o for o in r["overrides"] if o not in common)
    return rows


def write_tables(sweep_dir: Path, rows: list[dict[str, Any]]) -> tuple[Path, Path]:
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    csv_path, md_path = Path(sweep_dir) / "metrics.csv", Path(sweep_dir) / "metrics.md"
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)

    def fmt(v: Any) -> str:
        return f"{v:.4g}" if isinstance(v, float) else ("" if v is None else str(v))

    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in cols) + " |" for r in rows]
    md_path.write_text("\n".join(lines) + "\n")
    from qmdf.report import sweep_report

    sweep_report(sweep_dir, rows)  # report.html beside them, linking each job's own report
    return csv_path, md_path


try:
    from hydra.experimental.callback import Callback
except ImportError:  # pragma: no cover - Hydra is a dependency
    Callback = object  # type: ignore[misc,assignment]


class CollectMetrics(Callback):
    """Hydra callback: after a multirun, write the table of its jobs."""

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        if sweep_dir.exists():
            csv_path, md_path = write_tables(sweep_dir, collect(sweep_dir))
            print(f"qmdf sweep table: {md_path}", flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m qmdf.sweep SWEEP_DIR")
    path = Path(sys.argv[1])
    print(write_tables(path, collect(path))[1].read_text(), end="")
