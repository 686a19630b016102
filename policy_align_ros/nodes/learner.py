"""``learner``: learn a PolicyAlign model from the demonstrations in ``dataset_dir``.

``~/learn`` (std_srvs/Trigger) runs the package's one learning pipeline,
:func:`policy_align_ros.data.pipeline.learn_pipeline` (discovery, de-duplication, hold-out
split, fit, quality summary, degenerate-fit refusal), on ``dataset_dir``. When the fit
passes the gates (or ``force`` is set) the model is written atomically to ``model_path``
with the summary in its header, its path is published on ``~/model`` (std_msgs/String,
transient local) and the answer is the summary's one line. A refused fit answers
``success=false`` with the reasons, leaves ``model_path`` unchanged and publishes nothing,
so an executor never hot-loads it. The fit runs in its own callback group on a
multi-threaded executor, so the node keeps serving its other callbacks; a second
``~/learn`` while one runs is refused. Bad or missing data gives ``success=false`` with
the reason, never a crash.

The run's Python warnings (the fit's: a poor fit, a goal that is not a minimum, ...) go
through the node's logger at WARN, each text once, not to stderr with a source file and
line; numerical ones (numpy's overflow or invalid value, a ``RuntimeWarning``) are
counted in one line (:func:`~policy_align_ros.data.learn.warning_lines`, as ``policy-align
learn`` says them). The answer is logged once: INFO when written, ERROR when refused or
failed.
"""

from __future__ import annotations

import threading
import traceback
import warnings
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger

from policy_align_ros.data.arguments import HOLDOUT_RANGE, parse_sigma, state_name
from policy_align_ros.data.fit_figure import figure_format, plot_fit
from policy_align_ros.data.learn import warning_lines
from policy_align_ros.data.pipeline import PipelineResult, learn_pipeline
from policy_align_ros.data.quality import Gates
from policy_align_ros.kinematics.robot_config import learning_robot
from policy_align_ros.nodes._common import (
    LATCHED_QOS,
    ROBOT_NAMES_TEXT,
    StartNode,
    accept,
    descriptor,
    optional_parameter,
    reject,
    run_node,
)

__all__ = ["Learner", "main"]

#: Gate parameters: name -> (description, range); defaults are those of :class:`Gates`.
_GATE_PARAMETERS = {
    "min_sigma2_fraction": (
        "refuse a fit whose sigma^2 (from a sigma rule) is below this fraction of the "
        "training states' variance", (0.0, 1.0)),
    "max_discarded_fraction": (
        "refuse a fit whose outlier detection finds more than this fraction of the "
        "training demonstrations too weakly connected to align", (0.0, 1.0)),
    "heldout_tolerance": (
        "refuse a fit whose held-out nCPE exceeds the current model's on the same "
        "demonstrations by more than this", (0.0, 10.0)),
    "duplicate_tol": (
        "demonstrations closer than this fraction of the data's RMS spread are "
        "duplicates and skipped", (0.0, 1.0)),
}

#: Parameter types ``sigma`` may have (a rule name, or sigma^2 as text or a number).
_SIGMA_TYPES = (Parameter.Type.STRING, Parameter.Type.DOUBLE, Parameter.Type.INTEGER)
#: How :meth:`PipelineResult.line` begins for a refused fit, which the pipeline also says
#: as progress: the node logs it once, as its answer.
_REFUSED = "refused: "


class Learner(StartNode):
    """The ``learner`` node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("learner", **kwargs)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.declare_parameter("dataset_dir", "demos", descriptor(
            "directory of rosbag2 demonstrations (one bag per demonstration)"))
        self.declare_parameter("model_path", "model.npz", descriptor(
            "where the learnt model is written (atomically)"))
        sigma = descriptor(
            "kernel width: narrow, medium, wide (paper eqs. 17-19) or sigma^2 as a number")
        # A number (``-p sigma:=0.05``) is a DOUBLE or INTEGER parameter, a rule name a
        # STRING: the type is dynamic and _on_set_parameters checks it.
        sigma.dynamic_typing = True
        self.declare_parameter("sigma", "medium", sigma)
        self.declare_parameter("joints", Parameter.Type.STRING_ARRAY, descriptor(
            "state joints and their order; unset = robot_config's, else the joints the "
            "bags share (less those that never move)"))
        self.declare_parameter("holdout_fraction", 0.2, descriptor(
            "fraction of demonstrations held out to report the nCPE",
            float_range=HOLDOUT_RANGE))
        self.declare_parameter("gap_s", 0.5, descriptor(
            "split recordings into demonstrations at time gaps longer than this [s]",
            float_range=(0.0, 3600.0)))
        self.declare_parameter("seed", 0, descriptor(
            "random seed of the hold-out split and the fit", int_range=(0, 2**31 - 1)))
        self.declare_parameter("state", "joints", descriptor(
            "state learnt in: joints, or frames:F1,F2 (stacked frame positions, m)"))
        self.declare_parameter("robot", "", descriptor(
            f"the robot the demonstrations were recorded on: {ROBOT_NAMES_TEXT}; stored "
            "in the model file (the executor takes it from there); gives the frames "
            "of a frames: state and the continuous joints to unwrap; empty = "
            "robot_config's, else none"))
        self.declare_parameter("robot_config", "", descriptor(
            "robot config (talos, panda, ur5 or a .yaml path): robot and joints when they "
            "are unset; empty = none"))
        self.declare_parameter("force", False, descriptor(
            "write the model even when the fit is refused as degenerate"))
        self.declare_parameter("overwrite", False, descriptor(
            "replace a model at model_path learnt for other joints or another state"))
        self.declare_parameter("plot_path", "", descriptor(
            "figure of each fit, refused or not, .png, .pdf or .svg "
            "(docs/design/fit_figure.md): the potential along each demonstration, runs "
            "from their starts; empty = none"))
        defaults = Gates()
        for name, (text, limits) in _GATE_PARAMETERS.items():
            self.declare_parameter(name, float(getattr(defaults, name)), descriptor(
                text, float_range=limits))
        self._busy = threading.Lock()
        self.last_result: PipelineResult | None = None
        self._pub = self.create_publisher(String, "~/model", LATCHED_QOS)
        self.create_service(Trigger, "~/learn", self._on_learn,
                            callback_group=ReentrantCallbackGroup())

    def _on_set_parameters(self, params: Sequence[Parameter]):
        for param in params:
            if param.name == "sigma":
                if param.type_ not in _SIGMA_TYPES:  # bool would pass as 1.0, None unset it
                    return reject(f"sigma: expected narrow, medium, wide or a positive "
                                  f"number, got {param.value!r}")
                try:
                    parse_sigma(param.value)
                except ValueError as err:
                    return reject(str(err))
            elif param.name in ("dataset_dir", "model_path") and not str(param.value).strip():
                return reject(f"{param.name}: must not be empty")
            elif param.name == "plot_path" and str(param.value).strip():
                try:
                    figure_format(str(param.value).strip())
                except ValueError as err:
                    return reject(f"plot_path: {err}")
            elif param.name == "state":
                try:
                    state_name(param.value)
                except ValueError as err:
                    return reject(str(err))
            elif param.name == "joints" and param.value is not None and (
                    len(set(param.value)) != len(param.value) or not param.value):
                return reject("joints: must be a non-empty list without repeats")
        return accept()

    def _on_learn(self, request: Trigger.Request, response: Trigger.Response):
        if not self._busy.acquire(blocking=False):
            response.success = False
            response.message = "a learning run is already in progress"
            return response
        # Recorded, not printed: Python's format (a source line of the package) is no
        # message for a user, and numpy repeats one warning per element.
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                self.get_logger().info("learning started")
                result = self._learn()
            except (ValueError, OSError) as err:
                response.success = False
                response.message = f"learning failed: {err}"
            except Exception as err:  # noqa: BLE001 - a service must answer, never crash
                self.get_logger().error(traceback.format_exc())
                response.success = False
                response.message = f"learning failed ({type(err).__name__}): {err}"
            else:
                self.last_result = result
                response.message = result.line() + self._draw(result)
                response.success = result.written
                if result.written:
                    self._pub.publish(String(data=str(result.model_path)))
            finally:
                self._busy.release()
        for line in warning_lines(caught):
            self.get_logger().warning(line)
        # Two call sites: rclpy refuses a second severity at one logging call site.
        if response.success:
            self.get_logger().info(response.message)
        else:
            self.get_logger().error(response.message)
        return response


    def _draw(self, result: PipelineResult) -> str:
        """``plot_path``'s figure of ``result``; what to add to the answer about it."""
        path = self.get_parameter("plot_path").value.strip()
        if not path:
            return ""
        try:
            return f"; fit drawn in {plot_fit(result.model, result.train, path, result.held)}"
        except (ValueError, OSError) as err:  # the model is the answer; the figure is extra
            return f"; could not draw {path}: {err}"

    def _learn(self) -> PipelineResult:
        """The learning pipeline on ``dataset_dir`` with the node's parameters."""
        value = self.get_parameter
        dataset = Path(value("dataset_dir").value).expanduser()
        if not dataset.exists():
            raise ValueError(
                f"dataset_dir: {dataset} does not exist (record demonstrations first)")
        robot, joints = learning_robot(value("robot").value,
                                       optional_parameter(self, "joints"),
                                       value("robot_config").value)
        return learn_pipeline(
            [dataset],
            value("model_path").value,
            sigma=parse_sigma(value("sigma").value),
            joints=joints,
            holdout_fraction=value("holdout_fraction").value,
            gap_s=value("gap_s").value,
            seed=value("seed").value,
            state=value("state").value,
            robot=robot,
            gates=Gates(**{f.name: value(f.name).value for f in fields(Gates)}),
            force=value("force").value,
            overwrite=value("overwrite").value,
            log=self._say,
        )

    def _say(self, message: str) -> None:
        """A progress line of the pipeline, at INFO; not its refusal, which is the answer
        and logged once with it, at ERROR."""
        if not message.startswith(_REFUSED):
            self.get_logger().info(message)


def main(args: Sequence[str] | None = None) -> int:
    """Console script ``learner``."""
    return run_node(Learner, args, executor_factory=lambda: MultiThreadedExecutor(2))


if __name__ == "__main__":
    raise SystemExit(main())
