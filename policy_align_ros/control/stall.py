"""Stall detection: a joint commanded to move that the measured positions show standing still.

A velocity-controlled joint that is blocked (a collision, a brake left on, a controller
that is not running or drives other joints) keeps receiving commands while it does not
move; nothing else in the executor notices, and the command may grow (a policy pulling
harder the further it is from its goal). :class:`StallDetector` compares, per joint and
over a sliding window of ``stall_time_s``,

* the **expected** displacement: the integral of the command passed through a
  first-order lag of time constant ``lag_s`` (a robot reaching the command with that
  time constant moves exactly this much), with
* the **measured** displacement: the difference of the joint positions at the ends of
  the window, by their stamps.

A joint stalls when, for the whole window, its command kept one sign and stayed at least
``min_speed`` in magnitude, and it moved along its command by less than ``fraction`` of
the expected displacement. Differences over a whole window rather than per-sample
velocities make encoder noise negligible (1e-4 rad over 0.5 s is 2e-4 rad/s), and the
lag model together with a window much longer than the lag keeps a robot that tracks with
a delay from counting as stalled. Commands near zero (a robot settling at its goal)
never count. A continuous joint, whose angle a driver reports modulo a turn, is followed
across the wrap: each sample is moved by whole turns to within half a turn of the one
before it (no joint turns half a turn in one sample period), so crossing +-pi is not a
jump of 2 pi against the command. Positions come from the joint states only: the
``velocity`` field of some drivers echoes the command (ros2_control's mock hardware
does), so it cannot show that the joint is not moving.

Times are integer nanoseconds of the caller's clock: command times on the node clock,
position times by their stamps (the two differ by at most the allowed clock skew, a
shift of the window that a window much longer than the skew tolerates).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from policy_align_ros.control.turns import nearest_turn

__all__ = ["DEFAULT_STALL_TIME_S", "MIN_STALL_TIME_S", "STALL_FRACTION", "STALL_LAG_S",
           "STALL_MIN_SPEED", "Stall", "StallDetector", "stall_time_problem"]

#: Default window (s): 10 periods of the tracking lag of a real arm (0.05 s).
DEFAULT_STALL_TIME_S = 0.5
#: Shortest window (s) other than 0 (off): shorter ones cannot tell a stall from the lag.
MIN_STALL_TIME_S = 0.1
#: A joint that moves less than this fraction of its expected displacement stalls.
STALL_FRACTION = 0.25
#: Commands below this speed (rad/s) never count: a robot settling at its goal.
STALL_MIN_SPEED = 0.05
#: Time constant of the tracking lag the expected displacement assumes (s).
STALL_LAG_S = 0.05


@dataclass(frozen=True)
class Stall:
    """A stall found by :meth:`StallDetector.find`.

    Attributes
    ----------
    joints : tuple of str
        The stalled joints, the one that moved the least along its command (relative to
        it) first.
    commanded : float
        That first joint's mean lagged command over the window, along its sign (rad/s, >
        0).
    moved : float
        Its mean measured speed along the same sign (rad/s; negative: against it).
    window_s : float
        Length of the window, by the joint states' stamps (s).
    text : str
        The stall in words (the controller's ``zero_reason``).
    """

    joints: tuple[str, ...]
    commanded: float
    moved: float
    window_s: float
    text: str


def stall_time_problem(value: float) -> str:
    """Why ``value`` (s) is no valid ``stall_time_s``; empty when it is."""
    if math.isfinite(value) and (value == 0.0 or value >= MIN_STALL_TIME_S):
        return ""
    return (f"stall_time_s: must be 0 (off) or >= {MIN_STALL_TIME_S:g} s (a shorter window "
            f"cannot tell a stall from the tracking lag), got {value}")


class StallDetector:
    """Per-joint comparison of commanded and measured motion over a sliding window.

    Feed it every command published while armed (:meth:`command`) and every accepted
    joint state (:meth:`position`); :meth:`find` (or :meth:`check`, in words) then says
    whether a joint stalls.
    :meth:`reset` starts afresh (at each arming).

    Parameters
    ----------
    n : int
        Number of joints.
    stall_time_s : float
        Window length (s); 0 turns detection off, otherwise >= :data:`MIN_STALL_TIME_S`.
    joint_names : sequence of str, optional
        Names used in the stall description (command order).
    fraction : float
        Measured-to-expected displacement ratio below which a joint stalls, in (0, 1).
    min_speed : float
        Smallest command magnitude that counts (rad/s), > 0.
    lag_s : float
        Tracking lag assumed for the expected displacement (s), >= 0.
    continuous : array_like of bool, shape (n,), optional
        Which joints are continuous (``Robot.continuous``): their measured angles are
        followed across the wrap at +-pi. None: no joint is.
    """

    def __init__(self, n: int, stall_time_s: float = DEFAULT_STALL_TIME_S, *,
                 joint_names: Sequence[str] | None = None, fraction: float = STALL_FRACTION,
                 min_speed: float = STALL_MIN_SPEED, lag_s: float = STALL_LAG_S,
                 continuous: Sequence[bool] | np.ndarray | None = None) -> None:
        if not (0.0 < fraction < 1.0):
            raise ValueError(f"fraction: must be in (0, 1), got {fraction}")
        if not (math.isfinite(min_speed) and min_speed > 0.0):
            raise ValueError(f"min_speed: must be finite and > 0, got {min_speed}")
        if not (math.isfinite(lag_s) and lag_s >= 0.0):
            raise ValueError(f"lag_s: must be finite and >= 0, got {lag_s}")
        self.n = int(n)
        self.joint_names = (list(joint_names) if joint_names is not None
                            else [f"joint {i}" for i in range(self.n)])
        if len(self.joint_names) != self.n:
            raise ValueError(f"joint_names: {len(self.joint_names)} names for {n} joints")
        self.continuous = (np.zeros(self.n, dtype=bool) if continuous is None
                           else np.asarray(continuous, dtype=bool))
        if self.continuous.shape != (self.n,):
            raise ValueError(f"continuous: expected {self.n} flags, got shape "
                             f"{self.continuous.shape}")
        self.fraction = float(fraction)
        self.min_speed = float(min_speed)
        self.lag_s = float(lag_s)
        self.stall_time_s = stall_time_s
        self.reset()

    @property
    def stall_time_s(self) -> float:
        """Window length (s); 0 = off."""
        return self._window_ns / 1e9

    @stall_time_s.setter
    def stall_time_s(self, value: float) -> None:
        value = float(value)
        problem = stall_time_problem(value)
        if problem:
            raise ValueError(problem)
        self._window_ns = round(value * 1e9)
        self.reset()

    @property
    def enabled(self) -> bool:
        """Whether detection is on (``stall_time_s > 0``)."""
        return self._window_ns > 0

    def reset(self) -> None:
        """Forget all history (at arming, or when the window changes)."""
        # (stamp_ns, q) of joint states; the first is the latest at or before the window.
        self._positions: deque[tuple[int, np.ndarray]] = deque()
        # (t_ns, integral P (n,), lag state y (n,), command c (n,)): the lagged command
        # integral and lag state at t_ns; c applies from t_ns until the next record.
        self._commands: deque[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = deque()
        # Since when each joint's command has kept its sign above min_speed (ns; inf: not).
        self._run_start = np.full(self.n, np.inf)
        self._run_sign = np.zeros(self.n)

    # -- inputs ---------------------------------------------------------------------
    def command(self, command: np.ndarray, now_ns: int) -> None:
        """The command ``command`` (n,) (rad/s) was published at ``now_ns`` and holds until
        the next one."""
        if not self.enabled:
            return
        c = np.asarray(command, dtype=float)
        now_ns = int(now_ns)
        if self._commands:
            t, integral, lagged, previous = self._commands[-1]
            if now_ns < t:  # a clock jumping back forgets the history (the caller disarms)
                self.reset()
                integral, lagged = np.zeros(self.n), np.zeros(self.n)
            else:
                integral, lagged = self._advance(integral, lagged, previous, (now_ns - t) / 1e9)
        else:
            integral, lagged = np.zeros(self.n), np.zeros(self.n)
        self._commands.append((now_ns, integral, lagged, c))
        sign = np.sign(c)
        above = np.abs(c) >= self.min_speed
        started = above & ((self._run_start == np.inf) | (sign != self._run_sign))
        self._run_start[started] = now_ns
        self._run_start[~above] = np.inf
        self._run_sign = np.where(above, sign, 0.0)
        self._trim_commands()

    def position(self, q: np.ndarray, stamp_ns: int) -> None:
        """An accepted joint state: positions ``q`` (n,) (rad) stamped ``stamp_ns``."""
        if not self.enabled:
            return
        stamp_ns = int(stamp_ns)
        positions = self._positions
        if positions and stamp_ns <= positions[-1][0]:
            if stamp_ns < positions[-1][0]:
                positions.clear()  # stamps going back: start the window again
            else:
                return
        q = np.array(q, dtype=float)
        if positions and self.continuous.any():
            # Continuous joints on the turn of the sample before: the window's difference
            # is then the motion, not the driver's wrap.
            q = nearest_turn(q, np.where(self.continuous, positions[-1][1], np.nan))
        positions.append((stamp_ns, q))
        start = stamp_ns - self._window_ns
        while len(positions) >= 2 and positions[1][0] <= start:
            positions.popleft()
        self._trim_commands()

    # -- the verdict ----------------------------------------------------------------
    def check(self) -> str:
        """The stall, described (joint, commanded and measured speed, window); empty when
        no joint stalls or the window is not full yet."""
        stall = self.find()
        return "" if stall is None else stall.text

    def find(self) -> Stall | None:
        """The stall (joints, commanded and measured speed, window, words); None when no
        joint stalls or the window is not full yet."""
        positions = self._positions
        if not self.enabled or len(positions) < 2 or not self._commands:
            return None
        (t0, q0), (t1, q1) = positions[0], positions[-1]
        if t1 - t0 < self._window_ns:
            return None
        candidates = self._run_start <= t0
        if not candidates.any():
            return None
        window_s = (t1 - t0) / 1e9
        sign = self._run_sign
        expected = sign * (self._integral_at(t1, from_end=True)
                           - self._integral_at(t0, from_end=False))
        measured = sign * (q1 - q0)
        stalled = (candidates & (expected > 0.5 * self.min_speed * window_s)
                   & (measured < self.fraction * expected))
        if not stalled.any():
            return None
        ratio = np.where(stalled, measured / np.where(stalled, expected, 1.0), np.inf)
        # Worst first; a stable sort keeps equal ratios in joint order.
        order = [int(i) for i in np.argsort(ratio, kind="stable") if stalled[i]]
        worst = order[0]
        others = len(order) - 1
        more = f" (and {others} more joint{'s' if others > 1 else ''})" if others else ""
        commanded = float(expected[worst] / window_s)
        moved = float(measured[worst] / window_s)
        text = (f"stall: {self.joint_names[worst]} commanded {commanded:.3f} rad/s but "
                f"moved {moved:.3f} rad/s along it for {window_s:.2f} s "
                f"(< {100 * self.fraction:g} % of the command; stall_time_s "
                f"{self.stall_time_s:g}){more}")
        return Stall(tuple(self.joint_names[i] for i in order), commanded, moved, window_s,
                     text)

    # -- internals ------------------------------------------------------------------
    def _advance(self, integral: np.ndarray, lagged: np.ndarray, c: np.ndarray,
                 dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Integral and lag state after ``dt_s`` s of the constant command ``c`` (n,)."""
        if self.lag_s <= 0.0:
            return integral + c * dt_s, c
        decay = math.exp(-dt_s / self.lag_s)
        gap = lagged - c
        return integral + c * dt_s + gap * (self.lag_s * (1.0 - decay)), c + gap * decay

    def _integral_at(self, t_ns: int, from_end: bool) -> np.ndarray:
        """The lagged command's integral (n,) (rad) at ``t_ns``; searched from the newest
        record (``from_end``) or the oldest, whichever lies nearer."""
        records = self._commands
        found = None
        if from_end:
            for record in reversed(records):
                if record[0] <= t_ns:
                    found = record
                    break
        else:
            for record in records:
                if record[0] > t_ns:
                    break
                found = record
        if found is None:  # before the first command: nothing commanded yet
            return np.zeros(self.n)
        t, integral, lagged, c = found
        return self._advance(integral, lagged, c, (t_ns - t) / 1e9)[0]

    def _trim_commands(self) -> None:
        """Drop command records older than needed for the window's start."""
        if not self._positions:
            return
        start = self._positions[0][0]
        records = self._commands
        while len(records) >= 2 and records[1][0] <= start:
            records.popleft()
