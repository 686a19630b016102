"""Copy benchmark and demo outputs into the docs between ``<!-- BEGIN x -->`` markers.

Usage: ``python tools/update_readme.py OUT_DIR`` where OUT_DIR holds the ``--out``
directories of the runs: ``suite/suite.md``, ``toy/toy.md``, ``grasp/grasp.md``,
``humanoid/humanoid.md``, ``executor/executor_bench.md`` and ``scale/scale.md`` (blocks in
``docs/benchmarks.md``) and ``demo/report.txt`` (block ``demo`` in ``README.md``). Figures
are copied to ``docs/``. The docs then show exactly what the commands printed. Outputs
missing from OUT_DIR leave their blocks and figures as they are.

``python tools/update_readme.py --params`` regenerates the parameter tables (block
``params`` of ``docs/parameters.md``) from the descriptors the nodes declare
(policy_align_ros.client.param_table); ``test/test_readme.py`` fails when they disagree
with the code.
"""

from __future__ import annotations

import re
import shutil
import sys
from pathlib import Path

README = Path("README.md")
BENCHMARKS = Path("docs/benchmarks.md")
PARAMETERS = Path("docs/parameters.md")
# block name -> (output file under OUT_DIR, code fence or None, document holding the block)
BLOCKS = {
    "suite": ("suite/suite.md", None, BENCHMARKS),
    "toy": ("toy/toy.md", None, BENCHMARKS),
    "grasp": ("grasp/grasp.md", None, BENCHMARKS),
    "humanoid": ("humanoid/humanoid.md", None, BENCHMARKS),
    "executor": ("executor/executor_bench.md", None, BENCHMARKS),
    "scale": ("scale/scale.md", None, BENCHMARKS),
    "demo": ("demo/report.txt", "```", README),
}
FIGURES = {"suite/suite.png": "suite.png", "toy/toy.png": "toy.png",
           "grasp/grasp.png": "grasp.png", "humanoid/humanoid.png": "humanoid.png",
           "demo/demo_distance.png": "demo_distance.png"}
# docs/demo_hands.png is the hands-state run's figure (``--seed 2 --state hands``, as its
# caption in docs/benchmarks.md says), not the joints demo's: copied by hand.


def replace_block(text: str, name: str, body: str) -> str:
    """``text`` with the lines between ``<!-- BEGIN name -->`` and ``<!-- END name -->``
    replaced by ``body``."""
    pattern = re.compile(rf"(<!-- BEGIN {name} -->\n).*?(<!-- END {name} -->)", re.S)
    if not pattern.search(text):
        raise SystemExit(f"no markers for block {name!r}")
    return pattern.sub(lambda m: m.group(1) + body + "\n" + m.group(2), text)


def update_params(target: Path = PARAMETERS) -> int:
    from policy_align_ros.client.param_table import parameter_tables

    target.write_text(replace_block(target.read_text(), "params", parameter_tables()))
    return 0


def main(out: Path) -> int:
    texts = {}
    for name, (source, fence, target) in BLOCKS.items():
        if not (out / source).exists():
            print(f"update_readme: no {out / source}; block {name!r} left as it is")
            continue
        body = (out / source).read_text().strip()
        body = re.sub(r"^#+ ", "### ", body, count=1) if fence is None else body
        if fence:
            body = f"{fence}\n{body}\n{fence}"
        text = texts[target] if target in texts else target.read_text()
        texts[target] = replace_block(text, name, body)
    for target, text in texts.items():
        target.write_text(text)
    for source, target in FIGURES.items():
        if (out / source).exists():
            shutil.copyfile(out / source, Path("docs") / target)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python tools/update_readme.py OUT_DIR | --params")
    sys.exit(update_params() if sys.argv[1] == "--params" else main(Path(sys.argv[1])))
