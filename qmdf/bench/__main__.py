"""``python -m qmdf.bench SUITE [options]``: run one benchmark suite and print its table."""

from __future__ import annotations

import sys

SUITES = {
    "models": "qmdf.bench.models",
    "extraction": "qmdf.bench.extraction",
    "field": "qmdf.bench.field",
    "features": "qmdf.bench.features",
    "speed": "qmdf.bench.speed",
    "faults": "qmdf.bench.faults",
    "clouds": "qmdf.bench.clouds",
}


def main(argv: list[str] | None = None) -> int:
    import importlib

    argv = list(sys.argv[1:] if argv is None else argv)
    usage = f"usage: python -m qmdf.bench {{{','.join(SUITES)}}} [--json PATH] [options]   (SUITE --help for each)"
    if argv and argv[0] in ("-h", "--help"):
        print(
            usage
            + "\n\n"
            + "\n".join(
                f"  {name:<11} {importlib.import_module(mod).__doc__.strip().splitlines()[0]}"
                for name, mod in SUITES.items()
            )
        )
        return 0
    if not argv or argv[0] not in SUITES:
        print(usage, file=sys.stderr)
        return 2
    return importlib.import_module(SUITES[argv[0]]).main(argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
