"""Write a synthetic runs folder (fake run records + TUM files) to preview ``agrivio compare`` and its report.

    .venv/bin/python scripts/make_sample_runs.py OUT_DIR

The numbers are synthetic (made-up error levels per variant), not results.
"""

from __future__ import annotations

import sys
from pathlib import Path

from eval.synthetic import synthetic_runset
from pipeline.atomic import write_text_atomic


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    root = Path(argv[0])
    files = synthetic_runset()
    for rel, text in files.items():
        write_text_atomic(root / rel, text)
    write_text_atomic(root / "inpaint_bench.md", "| method | hole RMSE (m) | note |\n|---|---|---|\n"
                                                 "| (sample) | 0.000 | placeholder table: run the inpainting "
                                                 "benchmark for real numbers |\n")
    print(f"wrote {len(files) + 1} files under {root}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
