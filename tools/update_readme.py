"""Copy benchmark and demo outputs into README.md between ``<!-- BEGIN x -->`` markers.

Usage: ``python tools/update_readme.py OUT_DIR`` where OUT_DIR holds the ``--out``
directories of the runs: ``suite/suite.md``, ``toy/toy.md``, ``grasp/grasp.md``,
``humanoid/humanoid.md``, ``executor/executor_bench.md``, ``scale/scale.md`` and
``demo/report.txt``. Figures are
copied to ``docs/``. The README then shows exactly what the commands printed. Outputs
missing from OUT_DIR leave their blocks and figures as they are.
"""

from __future__ import annotations

import re
import shutil
import sys
from pathlib import Path

BLOCKS = {
    "suite": ("suite/suite.md", None),
    "toy": ("toy/toy.md", None),
    "grasp": ("grasp/grasp.md", None),
    "humanoid": ("humanoid/humanoid.md", None),
    "executor": ("executor/executor_bench.md", None),
    "scale": ("scale/scale.md", None),
    "demo": ("demo/report.txt", "```"),
}
FIGURES = {"toy/toy.png": "toy.png", "grasp/grasp.png": "grasp.png",
           "humanoid/humanoid.png": "humanoid.png",
           "demo/demo_distance.png": "demo_distance.png", "demo/demo_hands.png": "demo_hands.png"}


def main(out: Path, readme: Path = Path("README.md")) -> int:
    text = readme.read_text()
    for name, (source, fence) in BLOCKS.items():
        if not (out / source).exists():
            print(f"update_readme: no {out / source}; block {name!r} left as it is")
            continue
        body = (out / source).read_text().strip()
        body = re.sub(r"^#+ ", "### ", body, count=1) if fence is None else body
        if fence:
            body = f"{fence}\n{body}\n{fence}"
        pattern = re.compile(rf"(<!-- BEGIN {name} -->\n).*?(<!-- END {name} -->)", re.S)
        if not pattern.search(text):
            raise SystemExit(f"README.md has no markers for {name}")
        text = pattern.sub(lambda m, b=body: m.group(1) + b + "\n" + m.group(2), text)
    readme.write_text(text)
    for source, target in FIGURES.items():
        if (out / source).exists():
            shutil.copyfile(out / source, Path("docs") / target)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python tools/update_readme.py OUT_DIR")
    sys.exit(main(Path(sys.argv[1])))
