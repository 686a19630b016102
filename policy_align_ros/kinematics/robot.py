"""Robot kinematics from URDF with Pinocchio, on a subset of joints.

Notation and units: ``q`` (n,) joint positions of the selected joints in rad (revolute)
or m (prismatic), in the order of :attr:`Robot.joint_names`; frame positions in m in the
world (base) frame; translational Jacobians ``J`` (3, n) in m/rad, expressed in
``pin.LOCAL_WORLD_ALIGNED`` (origin at the frame, axes of the world). Robots are loaded
fixed-base (no free-flyer); every joint outside the subset is locked at the reference
posture with ``pin.buildReducedModel``.

Names of example-robot-data robots (paths below
``<site-packages>/cmeel.prefix/share/example-robot-data/robots``):

========  ==========================================  ===========================
name      URDF                                        reference posture (SRDF)
========  ==========================================  ===========================
talos     talos_data/robots/talos_reduced.urdf        talos.srdf ``half_sitting``
panda     panda_description/urdf/panda.urdf           panda.srdf ``default``
ur5       ur_description/urdf/ur5_robot.urdf          none (zeros)
human     human_description/robots/human.urdf         none (zeros clipped to limits)
========  ==========================================  ===========================
"""

from __future__ import annotations

import difflib
import hashlib
import importlib.metadata
import math
import os
import sysconfig
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

__all__ = ["Robot", "ROBOTS", "check_frames", "robots_dir", "closest_names"]

#: example-robot-data name -> (URDF, SRDF or None, reference posture name or None).
ROBOTS: dict[str, tuple[str, str | None, str | None]] = {
    "talos": ("talos_data/robots/talos_reduced.urdf", "talos_data/srdf/talos.srdf",
              "half_sitting"),
    "talos_full": ("talos_data/robots/talos_full_v2.urdf", "talos_data/srdf/talos.srdf",
                   "half_sitting"),
    "panda": ("panda_description/urdf/panda.urdf", "panda_description/srdf/panda.srdf",
              "default"),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", None, None),
    "ur3": ("ur_description/urdf/ur3_robot.urdf", None, None),
    "ur10": ("ur_description/urdf/ur10_robot.urdf", None, None),
    "human": ("human_description/robots/human.urdf", None, None),
    "romeo": ("romeo_description/urdf/romeo.urdf", "romeo_description/srdf/romeo.srdf",
              "half_sitting"),
    "icub": ("icub_description/robots/icub.urdf", "icub_description/srdf/icub.srdf",
             "half_sitting"),
}

_ERD_SUBDIR = Path("cmeel.prefix") / "share" / "example-robot-data" / "robots"


def robots_dir() -> Path:
    """Directory holding the example-robot-data robot descriptions.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    FileNotFoundError
        If the ``example-robot-data`` package is not installed.
    """
    candidates: list[Path] = []
    try:
        dist = importlib.metadata.distribution("example-robot-data")
        candidates.append(Path(str(dist.locate_file(""))) / _ERD_SUBDIR)
    except importlib.metadata.PackageNotFoundError:
        pass
    candidates.append(Path(sysconfig.get_paths()["purelib"]) / _ERD_SUBDIR)
    candidates.append(Path(pin.__file__).resolve().parents[4] / "share" /
                      "example-robot-data" / "robots")
    for cand in candidates:
        if cand.is_dir():
            return cand
    raise FileNotFoundError(
        "example-robot-data robots directory not found (pip install example-robot-data); "
        f"looked in {', '.join(str(c) for c in candidates)}"
    )


def closest_names(name: str, valid: Sequence[str], n: int = 5) -> str:
    """Comma-separated list of the valid names closest to ``name`` (for error messages)."""
    close = difflib.get_close_matches(name, list(valid), n=n, cutoff=0.4)
    if not close:
        close = list(valid)[:n]
    return ", ".join(close)


def _unknown_frame(frame: str, robot: str, names: Sequence[str]) -> ValueError:
    return ValueError(f"frame: unknown frame {frame!r} for robot {robot!r}; closest valid "
                      f"names: {closest_names(str(frame), names)}")


def check_frames(name_or_urdf: str | os.PathLike, frames: Sequence[str]) -> None:
    """Check that the robot's description has every one of ``frames``, before any joint
    is chosen (a frame stays a frame of every reduced model).

    Parameters
    ----------
    name_or_urdf : str or path
        As for :meth:`Robot.load`.
    frames : sequence of str

    Raises
    ------
    ValueError
        For an unknown robot, a URDF that does not parse, or the first unknown frame
        (with the closest valid names).
    """
    names = [f.name for f in _parse_urdf(_resolve(name_or_urdf)[0]).frames]
    for frame in frames:
        if frame not in names:
            raise _unknown_frame(frame, str(name_or_urdf), names)


def _parse_urdf(urdf: Path) -> pin.Model:
    try:
        return pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as err:
        raise ValueError(f"robot: cannot parse URDF {str(urdf)!r}: {err}") from None


def _resolve(name_or_urdf: str | os.PathLike) -> tuple[Path, Path | None, str | None]:
    text = str(name_or_urdf)
    if text in ROBOTS:
        urdf, srdf, ref = ROBOTS[text]
        base = robots_dir()
        return base / urdf, (base / srdf if srdf else None), ref
    path = Path(text).expanduser()
    if path.suffix.lower() == ".urdf" or os.sep in text:
        if not path.is_file():
            raise ValueError(f"robot: URDF file {text!r} does not exist")
        return path, None, None
    raise ValueError(
        f"robot: unknown robot name {text!r}; closest known names: "
        f"{closest_names(text, sorted(ROBOTS))} (or give a path to a .urdf file)"
    )


def _reference_posture(model: pin.Model, srdf: Path | None, ref: str | None) -> np.ndarray:
    q = pin.neutral(model)
    if srdf is not None and ref is not None and srdf.is_file():
        pin.loadReferenceConfigurations(model, str(srdf), False)
        if ref in model.referenceConfigurations:
            q = np.array(model.referenceConfigurations[ref], dtype=float)
    # Neutral 0 may violate limits (e.g. a knee limited to [0.1, 2]): clip finite limits.
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    finite = np.isfinite(lo) & np.isfinite(hi) & (lo <= hi)
    q[finite] = np.clip(q[finite], lo[finite], hi[finite])
    return q


class Robot:
    """Kinematic model of a robot restricted to a subset of its 1-DoF joints.

    Build with :meth:`load`. Attributes
    ``joint_names`` (list of n str), ``lower``/``upper`` (n,) position limits,
    ``velocity_limit`` (n,) in rad/s or m/s, ``nq`` (= n), ``model``/``data`` (the reduced
    Pinocchio model and its data, built once), ``urdf`` (path), ``name``.

    A continuous joint (URDF ``continuous``: Pinocchio's unbounded revolute, configured by
    ``(cos, sin)`` of its angle) is one angle here, as ``/joint_states`` gives it, with
    infinite limits; Pinocchio's Jacobians already have one column per joint.
    """

    def __init__(self, model: pin.Model, q_ref: np.ndarray, *, name: str, urdf: Path,
                 joint_order: Sequence[str] | None = None) -> None:
        self.model = model
        self.data = model.createData()
        self.name = name
        self.urdf = urdf
        tree_names = [model.names[i] for i in range(1, model.njoints)]
        order = tree_names if joint_order is None else list(joint_order)
        idx = [tree_names.index(j) for j in order]
        joints = [model.joints[model.getJointId(j)] for j in order]
        iq = np.array([j.idx_q for j in joints], dtype=int)
        iv = np.array([j.idx_v for j in joints], dtype=int)
        continuous = np.array([_continuous(j) for j in joints], dtype=bool)
        # The reduced model keeps kinematic-tree order; public arrays use ``order``, so
        # the hot paths only scatter q into Pinocchio's (``_order``) and gather Jacobian
        # columns (``_columns``); None where that is the identity.
        plain = not continuous.any() and idx == list(range(len(idx)))
        self._order: np.ndarray | None = None if plain else iq
        self._columns: np.ndarray | None = None if plain else iv
        self._continuous = np.flatnonzero(continuous)
        self.joint_names: list[str] = order
        self.nq = len(order)
        self.lower = np.where(continuous, -np.inf,
                              np.array(model.lowerPositionLimit, dtype=float)[iq])
        self.upper = np.where(continuous, np.inf,
                              np.array(model.upperPositionLimit, dtype=float)[iq])
        self.velocity_limit = np.array(model.velocityLimit, dtype=float)[iv]
        self._q_ref = np.array(q_ref, dtype=float)[idx]
        self.frame_names: list[str] = [f.name for f in model.frames]
        #: Posture (joint -> its ``nq`` configuration values) at which every joint outside
        #: the subset is locked; filled by :meth:`load`.
        self.locked_posture: dict[str, list[float]] = {}
        self._frame_ids: dict[str, int] = {}
        for fid, frame in enumerate(model.frames):
            self._frame_ids.setdefault(frame.name, fid)

    @classmethod
    def load(cls, name_or_urdf: str | os.PathLike, joints: Sequence[str] | None = None,
             *, reference: Sequence[float] | dict[str, float] | None = None) -> Robot:
        """Load a robot by example-robot-data name or URDF path.

        Parameters
        ----------
        name_or_urdf : str or path
            A name of :data:`ROBOTS` (``talos``, ``panda``, ``ur5``, ``human``, ...) or a
            URDF file (meshes are not loaded, so ``package://`` paths need not resolve).
        joints : sequence of str, optional
            Joints to keep, in this order; ``None`` keeps every joint. All kept joints must
            be 1-DoF: revolute, continuous or prismatic.
        reference : array_like (nq_full,) or dict joint -> value, optional
            Posture at which the other joints are locked (and :meth:`neutral`); defaults
            to the SRDF reference posture, else zeros clipped to the limits.

        Raises
        ------
        ValueError
            For an unknown robot or joint name (listing the closest valid names), a
            repeated joint, a joint that is not 1-DoF, or a bad reference.
        """
        urdf, srdf, ref = _resolve(name_or_urdf)
        full = _parse_urdf(urdf)
        q_full = _reference_posture(full, srdf, ref)
        q_full = _apply_reference(full, q_full, reference)
        names = [full.names[i] for i in range(1, full.njoints)]
        if joints is None:
            keep = names
        else:
            if isinstance(joints, str):
                raise ValueError("joints: must be a list of joint names, got a string")
            keep = [str(j) for j in joints]
            if not keep:
                raise ValueError("joints: empty joint list (use None for all joints)")
            seen: set[str] = set()
            for j in keep:
                if j not in names:
                    raise ValueError(
                        f"joints: unknown joint {j!r} for robot {str(name_or_urdf)!r}; "
                        f"closest valid names: {closest_names(j, names)}"
                    )
                if j in seen:
                    raise ValueError(f"joints: joint {j!r} is listed twice")
                seen.add(j)
        for j in keep:
            jmodel = full.joints[full.getJointId(j)]
            if jmodel.nv != 1 or not (jmodel.nq == 1 or _continuous(jmodel)):
                raise ValueError(
                    f"joints: joint {j!r} is a {jmodel.shortname()} with nv={jmodel.nv}; "
                    "only 1-DoF revolute, continuous and prismatic joints are supported "
                    "(list the others' 1-DoF joints in joints, or leave them out to lock "
                    "them)"
                )
        lock = [full.getJointId(j) for j in names if j not in keep]
        model = pin.buildReducedModel(full, lock, q_full) if lock else full
        tree_keep = [n for n in names if n in keep]
        robot = cls(model, _subset(full, q_full, tree_keep), name=str(name_or_urdf),
                    urdf=urdf, joint_order=keep)
        robot.locked_posture = _locked_posture(full, q_full, keep)
        return robot

    def urdf_sha256(self) -> str:
        """Hex SHA-256 of the URDF file's bytes (identifies the kinematic description)."""
        return hashlib.sha256(Path(self.urdf).read_bytes()).hexdigest()

    def neutral(self) -> np.ndarray:
        """Reference posture of the joint subset, shape (n,)."""
        return self._q_ref.copy()

    @property
    def continuous(self) -> np.ndarray:
        """Which joints are continuous (n,) bool: one angle, no limits, any turn."""
        mask = np.zeros(self.nq, dtype=bool)
        mask[self._continuous] = True
        return mask

    def clip(self, q: np.ndarray) -> np.ndarray:
        """Clip joint positions (..., n) to the finite position limits."""
        lo = np.where(np.isfinite(self.lower), self.lower, -np.inf)
        hi = np.where(np.isfinite(self.upper), self.upper, np.inf)
        return np.clip(q, lo, hi)

    def frame_id(self, frame: str) -> int:
        """Pinocchio frame index of ``frame``.

        Raises
        ------
        ValueError
            If no frame has that name; lists the closest valid names.
        """
        try:
            return self._frame_ids[frame]
        except KeyError:
            raise _unknown_frame(frame, self.name, self.frame_names) from None

    def _pin_q(self, q: np.ndarray) -> np.ndarray:
        vec = np.asarray(q, dtype=float)
        if vec.shape != (self.nq,):
            raise ValueError(f"q: must have shape ({self.nq},), got {vec.shape}")
        if self._order is None:
            return vec
        out = np.empty(self.model.nq)
        out[self._order] = vec
        if self._continuous.size:
            angles = vec[self._continuous]
            at = self._order[self._continuous]
            out[at], out[at + 1] = np.cos(angles), np.sin(angles)
        return out

    def frame_position(self, q: np.ndarray, frame: str) -> np.ndarray:
        """World position of ``frame`` at joint positions ``q`` (n,); returns (3,) in m."""
        return self.frame_positions(q, [frame])[0]

    def frame_jacobian(self, q: np.ndarray, frame: str) -> np.ndarray:
        """Translational Jacobian of ``frame`` (3, n), LOCAL_WORLD_ALIGNED, in m/rad.

        One frame's Jacobian through the joints supporting it only (the constraints' hot
        path); :meth:`frames_kinematics` gives several frames in one pass.
        """
        jac = pin.computeFrameJacobian(self.model, self.data, self._pin_q(q),
                                       self.frame_id(frame), pin.LOCAL_WORLD_ALIGNED)
        return self._user_cols(jac[:3])

    def frame_positions(self, q: np.ndarray, frames: Sequence[str]) -> np.ndarray:
        """World positions (f, 3) in m of ``frames`` at ``q`` (n,), without Jacobians."""
        fids = [self.frame_id(f) for f in frames]
        pin.forwardKinematics(self.model, self.data, self._pin_q(q))
        pos = np.empty((len(fids), 3))
        for i, fid in enumerate(fids):
            pos[i] = pin.updateFramePlacement(self.model, self.data, fid).translation
        return pos

    def frames_kinematics(self, q: np.ndarray, frames: Sequence[str]
                          ) -> tuple[np.ndarray, np.ndarray]:
        """Positions (f, 3) in m and translational Jacobians (f, 3, n) in m/rad of frames.

        The one frame-kinematics path: one pass over the joints for all frames, on the
        model and data built once, Jacobians LOCAL_WORLD_ALIGNED (origin at the frame,
        axes of the world), columns in :attr:`joint_names` order.
        """
        fids = [self.frame_id(f) for f in frames]
        pin.computeJointJacobians(self.model, self.data, self._pin_q(q))
        pos = np.empty((len(fids), 3))
        jac = np.empty((len(fids), 3, self.nq))
        for i, fid in enumerate(fids):
            pos[i] = pin.updateFramePlacement(self.model, self.data, fid).translation
            full = pin.getFrameJacobian(self.model, self.data, fid, pin.LOCAL_WORLD_ALIGNED)
            jac[i] = self._user_cols(full[:3])
        return pos, jac

    def fixed_frame_placement(self, frame: str) -> pin.SE3:
        """World placement of a frame fixed to the world (``parentJoint`` 0).

        Raises
        ------
        ValueError
            If the frame is unknown or moves with the selected joints.
        """
        fid = self.frame_id(frame)
        placement = self.model.frames[fid]
        if placement.parentJoint != 0:
            raise ValueError(f"frame {frame!r} moves with the selected joints")
        return pin.SE3(placement.placement)

    def _user_cols(self, jac: np.ndarray) -> np.ndarray:
        if self._columns is None:
            return np.array(jac)
        return np.array(jac[:, self._columns])

    def random_configuration(self, rng: np.random.Generator, std: float = 0.1,
                             center: np.ndarray | None = None) -> np.ndarray:
        """Sample ``q ~ N(center, std^2 I)`` clipped to the limits, shape (n,)."""
        mean = self.neutral() if center is None else np.asarray(center, dtype=float)
        return self.clip(mean + std * rng.standard_normal(self.nq))

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, n={self.nq})"


def _locked_posture(full: pin.Model, q_full: np.ndarray, keep: Sequence[str]
                    ) -> dict[str, list[float]]:
    out = {}
    for jid in range(1, full.njoints):
        name = full.names[jid]
        if name not in keep:
            jm = full.joints[jid]
            out[name] = [float(v) for v in q_full[jm.idx_q:jm.idx_q + jm.nq]]
    return out


def _continuous(joint) -> bool:
    """Whether a Pinocchio joint model is an unbounded revolute (URDF ``continuous``)."""
    return joint.nq == 2 and joint.nv == 1 and joint.shortname().startswith("JointModelRUB")


def _subset(full: pin.Model, q_full: np.ndarray, keep: list[str]) -> np.ndarray:
    """The joint positions of ``keep`` (one each: a continuous joint's angle) in
    ``q_full``."""
    out = []
    for j in keep:
        jm = full.joints[full.getJointId(j)]
        c = q_full[jm.idx_q:jm.idx_q + jm.nq]
        out.append(math.atan2(c[1], c[0]) if _continuous(jm) else c[0])
    return np.array(out, dtype=float)


def _apply_reference(full: pin.Model, q_full: np.ndarray,
                     reference: Sequence[float] | dict[str, float] | None) -> np.ndarray:
    if reference is None:
        return q_full
    q = q_full.copy()
    if isinstance(reference, dict):
        names = [full.names[i] for i in range(1, full.njoints)]
        for joint, value in reference.items():
            if joint not in names:
                raise ValueError(
                    f"reference: unknown joint {joint!r}; closest valid names: "
                    f"{closest_names(joint, names)}"
                )
            jmodel = full.joints[full.getJointId(joint)]
            if _continuous(jmodel):
                q[jmodel.idx_q:jmodel.idx_q + 2] = math.cos(float(value)), math.sin(float(value))
                continue
            if jmodel.nq != 1:
                raise ValueError(f"reference: joint {joint!r} is not 1-DoF")
            q[jmodel.idx_q] = float(value)
        return q
    vec = np.asarray(reference, dtype=float)
    if vec.shape != (full.nq,):
        raise ValueError(f"reference: must have shape ({full.nq},), got {vec.shape}")
    if not np.all(np.isfinite(vec)):
        raise ValueError("reference: contains NaN or inf")
    return vec.copy()
