"""Copy benchmark and demo outputs into README.md between ``<!-- BEGIN x -->`` markers.

Usage: ``python tools/update_readme.py OUT_DIR`` where OUT_DIR holds the ``--out``
directories of the runs: ``suite/suite.md``, ``toy/toy.md``, ``grasp/grasp.md``,
``humanoid/humanoid.md``, ``executor/executor_bench.md``, ``scale/scale.md`` and
``demo/report.txt``. Figures are
copied to ``docs/``. The README then shows exactly what the commands printed. Outputs
missing from OUT_DIR leave their blocks and figures as they are.

``python tools/update_readme.py --params`` regenerates the parameter tables (block
``params``) from the descriptors the nodes declare (policy_align_ros.client.param_table);
``test/test_readme.py`` fails when they disagree with the code.
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
FIGURES = {"suite/suite.png": "suite.png", "toy/toy.png": "toy.png",
           "grasp/grasp.png": "grasp.png", "humanoid/humanoid.png": "humanoid.png",
           "demo/demo_distance.png": "demo_distance.png", "demo/demo_hands.png": "demo_hands.png"}


def replace_block(text: str, name: str, body: str) -> str:
    """``text`` with the lines between ``<!-- BEGIN name -->`` and ``<!-- END name -->``
    replaced by ``body``."""
    pattern = re.compile(rf"(<!-- BEGIN {name} -->\n).*?(<!-- END {name} -->)", re.S)
    if not pattern.search(text):
        raise SystemExit(f"README.md has no markers for {name}")
    return pattern.sub(lambda m: m.group(1) + body + "\n" + m.group(2), text)


def update_params(readme: Path = Path("README.md")) -> int:
    from policy_align_ros.client.param_table import parameter_tables

    readme.write_text(replace_block(readme.read_text(), "params", parameter_tables()))
    return 0


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
        text = replace_block(text, name, body)
    readme.write_text(text)
    for source, target in FIGURES.items():
        if (out / source).exists():
            shutil.copyfile(out / source, Path("docs") / target)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python tools/update_readme.py OUT_DIR | --params")
    sys.exit(update_params() if sys.argv[1] == "--params" else main(Path(sys.argv[1])))
