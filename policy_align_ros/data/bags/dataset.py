"""Demonstrations from rosbag2 bags: read, split into segments, select joints, report.

:func:`load_dataset` runs in stages: discovery (bags named by the inputs, a bag named twice
read once), joint selection (given, or voted by the bags), reading each bag's JointState
streams into demonstrations split at time gaps (:class:`_Reading`), and the report of what
was used and skipped. Stamps are integer nanoseconds since the epoch, trajectory times
seconds from a demonstration's first sample, positions and velocities in the joints' units.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from policy_align_ros.data.bags.format import JOINT_STATE
from policy_align_ros.data.bags.read import (
    BagOpenError,
    bag_topics,
    find_bags,
    read_joint_states,
)
from policy_align_ros.data.messages import (
    NEW,
    SKIP,
    SKIP_REASONS,
    JointSelector,
    StreamClock,
    describe_foreign,
)
from policy_align_ros.learning import Trajectory

__all__ = ["DatasetReport", "DemoInfo", "load_dataset"]


@dataclass
class DemoInfo:
    """Where one demonstration came from.

    Attributes
    ----------
    bag : str
        Bag path.
    topic : str
        JointState topic.
    start_ns : int
        Stamp of the first sample (ns since the epoch); trajectory times are relative to it.
    n_samples : int
        Number of samples.
    name : str
        Unique name of the demonstration: the bag's name (``parent/bag`` when bags of
        different directories share a name, and for bare ``.mcap``/``.db3`` files),
        with ``#1``, ``#2``, ... appended when one bag holds several demonstrations
        (time gaps or several topics).
    """

    bag: str
    topic: str
    start_ns: int
    n_samples: int
    name: str = ""


@dataclass
class DatasetReport:
    """What :func:`load_dataset` read, used and skipped.

    Attributes
    ----------
    bags : list of str
        Bags read, in order.
    topics : list of str
        JointState topics found.
    messages_read, messages_used : int
        JointState messages decoded and accepted.
    skipped : dict of str to int
        Skipped messages by reason (:data:`SKIP_REASONS` plus ``undecodable``).
    demos_found, demos_too_short : int
        Segments found, and how many had fewer than ``min_samples`` samples.
    demos : list of DemoInfo
        The demonstrations returned, in order.
    errors : list of str
        Bags of a dataset directory that could not be opened, and bags whose reading
        stopped early (for example a truncated file; what was read before is kept).
    skipped_bags : list of (str, str)
        Every bag that gave no demonstration, with the reason (unreadable, no JointState
        topic, joints missing, every message malformed, too short).
    cut_short_bags : list of (str, str)
        Bags whose reading stopped early but that gave demonstrations (what was read
        before the damage is used), with the reason.
    repeated_bags : list of str
        Bags named more than once by the inputs (each is read once).
    available_joints : list of str
        Joint names seen in the JointState messages, in order of first appearance.
    missing_joints : list of str
        Selected joints that no JointState message carries.
    """

    bags: list[str] = field(default_factory=list)
    topics: list[str] = field(default_factory=list)
    messages_read: int = 0
    messages_used: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    demos_found: int = 0
    demos_too_short: int = 0
    demos: list[DemoInfo] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    skipped_bags: list[tuple[str, str]] = field(default_factory=list)
    cut_short_bags: list[tuple[str, str]] = field(default_factory=list)
    repeated_bags: list[str] = field(default_factory=list)
    available_joints: list[str] = field(default_factory=list)
    missing_joints: list[str] = field(default_factory=list)

    @property
    def messages_skipped(self) -> int:
        """Total number of skipped messages."""
        return sum(self.skipped.values())

    def summary(self) -> str:
        """One-line human-readable account."""
        skipped = ", ".join(f"{k}={v}" for k, v in self.skipped.items() if v) or "none"
        text = (
            f"{len(self.bags)} bag(s), {self.messages_read} JointState messages, "
            f"{self.messages_used} used, skipped: {skipped}; "
            f"{self.demos_found - self.demos_too_short} demonstration(s) "
            f"({self.demos_too_short} too short)"
        )
        if self.errors:
            text += f"; {len(self.errors)} bag(s) unreadable or cut short"
        if self.repeated_bags:
            text += f"; {len(self.repeated_bags)} bag(s) named twice, read once"
        return text

    def joint_problem(self) -> str:
        """Which selected joints are missing and which exist (empty when none is missing)."""
        if not self.missing_joints:
            return ""
        shown = ", ".join(self.available_joints[:40])
        more = len(self.available_joints) - 40
        return (f"joint(s) {', '.join(map(repr, self.missing_joints))} not found in any "
                f"JointState message; available: {shown or 'none'}"
                + (f" and {more} more" if more > 0 else ""))


class _Segment:
    """Accumulates one demonstration of one topic."""

    def __init__(self, topic: str, start_ns: int) -> None:
        self.topic = topic
        self.stamps: list[int] = []
        self.positions: list[list[float]] = []
        self.velocities: list[list[float]] = []
        self.all_velocities = True
        self.start_ns = start_ns


def load_dataset(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    joints: Sequence[str] | None = None,
    gap_s: float = 0.5,
    *,
    min_samples: int = 2,
) -> tuple[list[Trajectory], list[str], DatasetReport]:
    """Read demonstrations from rosbag2 bags and dataset directories.

    Every JointState topic of every bag is a stream: joints are matched by name, the
    stream is split into demonstrations at gaps of more than ``gap_s`` seconds (and never
    across bags or topics), and malformed messages are skipped and counted (see
    :mod:`policy_align_ros.data.messages`).

    Parameters
    ----------
    paths : path-like or iterable of path-like
        Bag directories, ``.mcap``/``.db3`` files, or dataset directories of bags.
    joints : sequence of str, optional
        Joint order of the state. Default: the joint set shared by most bags, each bag
        voting with the names of its first valid message (as a set; the order is that
        of the first bag voting for it); a tie goes to the set of the bag first in
        order. Bags whose joints do not cover it are skipped and named.
    gap_s : float
        Split threshold in seconds; ``0`` never splits at a gap. A restarted clock
        (stamps jumping back, :attr:`~policy_align_ros.data.messages.StreamClock.
        restart_s`) always ends a demonstration: what follows is not spliced onto it.
    min_samples : int
        Demonstrations with fewer samples are dropped and counted as too short.

    Returns
    -------
    trajectories : list of Trajectory
        Positions (N_k, n), times (N_k,) in seconds from the demo's start, and velocities
        (N_k, n) when every message of the demonstration had them.
    joint_names : list of str, length n
    report : DatasetReport

    Raises
    ------
    ValueError
        On a missing path, a path that is not a bag or dataset, bad arguments, or when no
        demonstration is usable; the message names the path(s).
    """
    paths = _check_arguments(paths, gap_s, min_samples)
    sources, repeated = _discover(paths)
    bags = [bag for bag, _ in sources]
    selector, first_names = _select_joints(bags, joints)
    report = DatasetReport(bags=[str(b) for b in bags], repeated_bags=repeated)
    reading = _Reading(selector, gap_s, min_samples, report)
    for bag, explicit in sources:
        reading.read_bag(bag, explicit, first_names.get(bag))
    return reading.finish(paths, joints)


def _check_arguments(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    gap_s: float,
    min_samples: int,
) -> list[str | os.PathLike[str]]:
    """The inputs as a list, after checking them and the splitting arguments."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise ValueError("paths: no bag or dataset given")
    if not (np.isfinite(gap_s) and gap_s >= 0):
        raise ValueError(f"gap_s: must be a finite number >= 0, got {gap_s}")
    if int(min_samples) < 2:
        raise ValueError(f"min_samples: must be >= 2, got {min_samples}")
    return paths


def _discover(
    paths: list[str | os.PathLike[str]],
) -> tuple[list[tuple[Path, bool]], list[str]]:
    """The bags to read, each with whether it was named explicitly, and the repeated ones.

    Bags named explicitly must open; an unreadable bag inside a dataset is reported.
    A bag named twice (``learn demos demos``) is read once: its copy would only add an
    identical demonstration, which collapses the kernel width of the alignment.
    """
    sources: list[tuple[Path, bool]] = []
    seen: dict[Path, int] = {}
    repeated: list[str] = []
    for p in paths:
        for bag in find_bags(p):
            key = bag.resolve()
            explicit = bag == Path(p)
            if key in seen:
                repeated.append(str(bag))
                k = seen[key]
                sources[k] = (sources[k][0], sources[k][1] or explicit)
                continue
            seen[key] = len(sources)
            sources.append((bag, explicit))
    return sources, repeated


def _select_joints(
    bags: list[Path], joints: Sequence[str] | None
) -> tuple[JointSelector, dict[Path, list[str]]]:
    """The joint selector, and each bag's joints of its first valid message when voted.

    Joints from the first message read would let one foreign bag that sorts first reject
    every other bag: without ``joints``, the bags vote (:func:`_majority_joints`).
    """
    selector = JointSelector(joints)
    first_names: dict[Path, list[str]] = {}
    if joints is None:
        first_names = {bag: names for bag in bags if (names := _first_names(bag))}
        chosen = _majority_joints(list(first_names.values()))
        if chosen:
            selector.set_joints(chosen)
    return selector, first_names


class _BagPass:
    """What reading one bag found so far: its streams, skips and joint names."""

    def __init__(self) -> None:
        self.clocks: dict[str, StreamClock] = {}
        self.segments: dict[str, _Segment | None] = {}
        self.counts: Counter[str] = Counter()
        self.names: dict[str, None] = {}  # ordered set of the bag's joint names
        self.name_lists: set[tuple[str, ...]] = set()  # real streams repeat one or two lists
        self.n_read = 0


class _Reading:
    """One pass of :func:`load_dataset` over its bags: demonstrations and the report."""

    def __init__(self, selector: JointSelector, gap_s: float, min_samples: int,
                 report: DatasetReport) -> None:
        self.selector = selector
        self.min_samples = min_samples
        self.gap_ns = round(gap_s * 1e9)
        self.report = report
        self.counts: Counter[str] = Counter({reason: 0 for reason in SKIP_REASONS})
        self.available: dict[str, None] = {}  # ordered set of joint names seen
        self.trajectories: list[Trajectory] = []

    def read_bag(self, bag: Path, explicit: bool, own: list[str] | None) -> None:
        """Read one bag's demonstrations; name the bag when it gives none.

        ``own`` is the bag's joints of its first valid message when the joints were voted.
        """
        report = self.report
        one = _BagPass()
        demos_before = len(self.trajectories)
        found_before, short_before = report.demos_found, report.demos_too_short
        failure = ""
        try:
            # Undecodable messages counted per bag too, or a bag of nothing else would be
            # reported as holding no JointState message at all.
            for message in read_joint_states(bag, one.counts):
                self._take(bag, one, *message)
        except BagOpenError as err:
            if explicit:
                raise
            report.errors.append(str(err))
            failure = str(err).removeprefix(f"{bag}: ")
        except Exception as err:  # a damaged bag keeps what was read
            report.errors.append(f"{bag}: {err}")
            failure = f"reading stopped after {one.n_read} message(s): {err}"
        self.counts["undecodable"] += one.counts["undecodable"]
        for segment in one.segments.values():
            self._close(segment, bag)
        for name in one.names:
            self.available.setdefault(name, None)
        if failure and len(self.trajectories) > demos_before:
            report.cut_short_bags.append((str(bag), failure))
        if len(self.trajectories) == demos_before:
            reason = failure or _no_demo_reason(
                one.n_read, one.counts, report.demos_found - found_before,
                report.demos_too_short - short_before, self.min_samples,
                self.selector.joints, list(one.names))
            if not failure and not one.n_read and not one.counts["undecodable"]:
                reason += "; " + _topics_text(bag)
            joints = self.selector.joints
            if not failure and own and joints and not set(joints) <= set(own):
                # Joints chosen by vote: which set this bag has instead is the whole story
                # (the same words for every such bag, so that a summary can group them).
                reason = (f"joints {', '.join(own)}; expected {', '.join(joints)}, the "
                          "joints most bags have: every message skipped")
            report.skipped_bags.append((str(bag), reason))

    def _take(self, bag: Path, one: _BagPass, topic: str, stamp: int, names: list[str],
              pos: np.ndarray, vel: np.ndarray, eff: np.ndarray) -> None:
        """Add one decoded message to its topic's demonstration, or count why it is skipped."""
        report = self.report
        report.messages_read += 1
        one.n_read += 1
        key = tuple(names)
        if key not in one.name_lists and len(one.name_lists) < 64:
            one.name_lists.add(key)
            for name in names:
                one.names.setdefault(str(name), None)
        clock = one.clocks.get(topic)
        if clock is None:
            clock = one.clocks[topic] = StreamClock(self.gap_ns)
            one.segments[topic] = None
            if topic not in report.topics:
                report.topics.append(topic)
        picked = self.selector.select(names, pos, vel, eff)
        if isinstance(picked, str):
            self.counts[picked] += 1
            one.counts[picked] += 1
            return
        outcome = clock.step(stamp)
        if outcome == SKIP and clock.restart_s:
            outcome = NEW  # a restarted clock ends a demonstration even with no gap split
        if outcome == SKIP:
            self.counts["time_not_increasing"] += 1
            one.counts["time_not_increasing"] += 1
            return
        self.selector.commit(names)
        clock.accept(stamp)
        segment = one.segments[topic]
        if outcome == NEW:
            self._close(segment, bag)
            segment = one.segments[topic] = _Segment(topic, stamp)
        assert segment is not None
        segment.stamps.append(stamp)
        segment.positions.append(picked[0])
        if picked[1] is None:
            segment.all_velocities = False
        else:
            segment.velocities.append(picked[1])
        report.messages_used += 1

    def _close(self, segment: _Segment | None, bag: Path) -> None:
        """End a demonstration: keep it, or count it as too short."""
        report = self.report
        if segment is None or not segment.stamps:
            return
        report.demos_found += 1
        if len(segment.stamps) < self.min_samples:
            report.demos_too_short += 1
            return
        stamps = np.asarray(segment.stamps, dtype=np.int64)
        k = len(self.trajectories)
        self.trajectories.append(
            Trajectory(
                np.asarray(segment.positions, dtype=np.float64),
                (stamps - stamps[0]) * 1e-9,
                np.asarray(segment.velocities) if segment.all_velocities else None,
                name=f"{k} ({bag.name}{segment.topic} @ {stamps[0]} ns)",
            )
        )
        report.demos.append(DemoInfo(str(bag), segment.topic, int(stamps[0]), len(stamps)))

    def finish(self, paths: list[str | os.PathLike[str]], joints: Sequence[str] | None
               ) -> tuple[list[Trajectory], list[str], DatasetReport]:
        """Complete the report and return what :func:`load_dataset` returns.

        Raises
        ------
        ValueError
            When no demonstration is usable, naming the paths and the missing joints.
        """
        report = self.report
        report.skipped = {k: v for k, v in self.counts.items() if v or k in SKIP_REASONS}
        report.available_joints = list(self.available)
        if joints is not None:
            report.missing_joints = [j for j in joints if j not in self.available]
        _name_demos(report.demos)
        if not self.trajectories:
            where = ", ".join(str(p) for p in paths)
            problem = report.joint_problem()
            # Each bag's reason (a bag of other topics lists them): the fix is in there.
            reasons = "; ".join(f"{_tail(bag, 2)}: {why}"
                                for bag, why in report.skipped_bags[:3])
            more = len(report.skipped_bags) - 3
            raise ValueError(f"{where}: no usable demonstrations"
                             + (f": {problem}" if problem else "") + f" ({report.summary()})"
                             + (f"; {reasons}" if reasons else "")
                             + (f" and {more} more bag(s)" if more > 0 else ""))
        assert self.selector.joints is not None
        return self.trajectories, list(self.selector.joints), report


def _topics_text(bag: Path) -> str:
    """The bag's topics for a reader told to look for JointState there (one phrase)."""
    topics = bag_topics(bag)
    if not topics:
        return "the bag has no topics"
    shown = ", ".join(f"{topic} ({msgtype}, {count} messages)"
                      for topic, msgtype, count in topics[:20])
    more = f" and {len(topics) - 20} more" if len(topics) > 20 else ""
    return (f"the bag's topics: {shown}{more} (record the robot's {JOINT_STATE} topic, "
            "for example ros2 bag record /joint_states)")


def _first_names(bag: Path) -> list[str]:
    """Joint names of the bag's first valid JointState message (empty if none/unreadable)."""
    probe = JointSelector(None)
    try:
        for _, _, names, pos, vel, eff in read_joint_states(bag):
            if not isinstance(probe.select(names, pos, vel, eff), str):
                return [str(n) for n in names]
    except Exception:  # the main pass reports unreadable and damaged bags
        pass
    return []


def _majority_joints(sets: list[list[str]]) -> list[str] | None:
    """The joint set most bags share (order of its first bag; ties: the first seen)."""
    votes: Counter[frozenset[str]] = Counter()
    order: dict[frozenset[str], list[str]] = {}
    for names in sets:
        key = frozenset(names)
        votes[key] += 1
        order.setdefault(key, names)
    if not votes:
        return None
    best = max(votes.values())
    # dicts keep insertion order, so the first set reaching the maximum is the earliest.
    return next(order[k] for k in order if votes[k] == best)


def _no_demo_reason(
    n_read: int,
    counts: Counter[str],
    found: int,
    too_short: int,
    min_samples: int,
    joints: Sequence[str] | None,
    names: list[str],
) -> str:
    """Why a bag that opened gave no demonstration (one line).

    ``n_read`` counts the decoded messages; ``counts["undecodable"]`` those that were not.
    """
    undecodable = counts["undecodable"]
    if n_read == 0 and not undecodable:
        return f"no {JOINT_STATE} messages"
    if found and found == too_short:
        return (f"{found} demonstration(s), all shorter than {min_samples} samples")
    parts = [f"{reason}={n}" for reason, n in counts.items() if n]
    text = f"all {n_read + undecodable} JointState message(s) skipped ({', '.join(parts)})"
    if joints and (counts["missing_joints"] or counts["unknown_joints"]):
        # The words the recorder and the executor use for one such message, over every
        # joint name the bag's messages carry.
        text += "; " + describe_foreign(joints, names, carrier="its messages name")
    return text


def _name_demos(demos: list[DemoInfo]) -> None:
    """Give every demonstration a unique, readable name (see :class:`DemoInfo`)."""
    paths = sorted({d.bag for d in demos})
    # A bare storage file's own name (``demo_0002.mcap``) rarely says where it lies: a
    # directory without metadata.yaml or a copied bag names it better.
    depth = {bag: 1 if Path(bag).suffix not in (".mcap", ".db3") else 2 for bag in paths}
    while True:
        names: dict[str, list[str]] = {}
        for bag in paths:
            names.setdefault(_tail(bag, depth[bag]), []).append(bag)
        clashing = [bag for group in names.values() if len(group) > 1 for bag in group
                    if depth[bag] < len(Path(bag).parts)]
        if not clashing:  # unique (distinct paths differ at the latest in full)
            break
        # Bags of one name in several datasets (``ds1/a/demo_0000``, ``ds2/a/demo_0000``):
        # one more parent each until they differ.
        for bag in clashing:
            depth[bag] += 1
    per_bag = Counter(d.bag for d in demos)
    index: Counter[str] = Counter()
    for d in demos:
        base = _tail(d.bag, depth[d.bag])
        index[d.bag] += 1
        d.name = base if per_bag[d.bag] == 1 else f"{base}#{index[d.bag]}"


def _tail(path: str, depth: int) -> str:
    """The last ``depth`` components of ``path``, joined by ``/`` (all of it, as given,
    from its root on)."""
    parts = Path(path).parts
    return str(Path(path)) if depth >= len(parts) else "/".join(parts[-depth:])
