"""Robustness cases of the datasets: bags that are malformed, foreign or damaged, each in a
dataset of good bags and on its own (``policy-align learn``)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from robustness_harness import J2, MS, T0, Lab, Result, Run


# --- writing bad bags -------------------------------------------------------------------
def write_raw_bag(path: Path, messages: Sequence[tuple], *, storage: str = "mcap",
                  topic: str = "/joint_states", msgtype: str = "sensor_msgs/msg/JointState"
                  ) -> Path:
    """A bag of arbitrary messages, as another tool could write it.

    ``messages`` are ``(stamp_ns, names, positions, velocities)`` for JointState, or
    ``(stamp_ns, text)`` for ``std_msgs/msg/String``. The bag (receive) times increase by
    1 ms a message from the first stamp whatever the header stamps do, as in a recording.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8 if storage != "mcap" else 9, storage_plugin=plugin) as writer:
        conn = writer.add_connection(topic, msgtype, typestore=store)
        cls = store.types[msgtype]
        received = int(messages[0][0]) if messages else T0
        for k, item in enumerate(messages):
            stamp = int(item[0])
            if msgtype.endswith("String"):
                msg = cls(data=item[1])
            else:
                header = store.types["std_msgs/msg/Header"](
                    stamp=store.types["builtin_interfaces/msg/Time"](
                        sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="")
                msg = cls(header=header, name=list(item[1]),
                          position=np.asarray(item[2], dtype=float),
                          velocity=np.asarray(item[3], dtype=float), effort=np.empty(0))
            writer.write(conn, received + k * MS, store.serialize_cdr(msg, msgtype))
    return path


def _good_messages(n: int = 40, start: int = T0 + 10**12) -> list[tuple]:
    return [(start + k * 50 * MS, J2, [0.5 - 0.01 * k, -0.3 + 0.005 * k], [])
            for k in range(n)]


def _learn_outcome(r: Result, run: Run, model: Path, good_bags: Sequence[str]) -> None:
    """Fill crash/traceback, and count the good bags silently left out of a written model.

    A bag reached the fit when the written model's training summary names it (used, held
    out or discarded as an outlier or duplicate are all decisions about it). A refused
    ``learn`` (no model, a reason on stderr) loses nothing: the bags stay on disk, and the
    verdict says whether refusing was right. ``lost`` stays None for a header that names
    no bag.
    """
    r.crash, r.traceback = run.crashed, run.traceback
    r.data.update(code=run.code, err=run.err, out=run.out)
    if run.code != 0 or not model.is_file():
        r.lost = 0
        return
    with np.load(model, allow_pickle=False) as data:
        header = json.loads(str(data["__header__"]))
    text = json.dumps(header.get("training", {}))
    named = [b for b in good_bags if b in text]
    r.lost = len(good_bags) - len(named) if named else None
    r.data["header"] = header


# --- the cases -------------------------------------------------------------------------
def _bag_case(lab: Lab, case: str, tried: str, make_bad: Callable[[Path], Path],
              alone_code: int | None = 2, alone: bool = True, extra: Sequence[str] = ()
              ) -> Result:
    """A bad bag inside the good dataset (``learn DATASET``), and on its own.

    Beside good bags the fit must go ahead with every good demonstration and name the bad
    bag (``alone=False``: a valid bag, which must simply be used); alone, ``learn`` must
    stop with ``alone_code`` and a message naming the bag.
    """
    dataset = lab.dataset_with(case)
    good = sorted(p.name for p in dataset.iterdir())
    bad = make_bad(dataset)
    model = dataset.parent / f"{case}.npz"
    run = lab.cli("learn", str(dataset), "--out", str(model), *extra)
    r = Result(case, "bags", tried)
    _learn_outcome(r, run, model, good)
    n = len(good)
    r.expect(run.code == 0, f"with {n} good bags beside it: exit {run.code} ({run.line()})")
    if run.code == 0:
        used = "?" if r.lost is None else str(len(good) - r.lost)
        note = run.skipped(130) or "nothing reported"
        r.behaviour = f"beside {n} good bags: exit 0, {used}/{n} good demos used; {note}"
        if alone:
            r.expect(bad.name in run.err + run.out, "beside good bags it is not named")
    else:
        r.behaviour = f"beside {n} good bags: exit {run.code}: {run.line(150)}"
    if alone:
        solo = lab.path(f"{case}_alone")
        target = solo / bad.name
        (shutil.copytree if bad.is_dir() else shutil.copy)(bad, target)
        run2 = lab.cli("learn", str(target), "--out", str(solo / "m.npz"))
        r.crash |= run2.crashed
        r.traceback |= run2.traceback
        r.data["alone"] = {"code": run2.code, "err": run2.err, "out": run2.out}
        r.behaviour += f". Alone: exit {run2.code}: {run2.line(130)}"
        if alone_code is not None:
            r.expect(run2.code == alone_code, f"alone: exit {run2.code}, expected {alone_code}")
            r.expect(bad.name in run2.out + run2.err, "alone: the message does not name the bag")
    return r


def _raw(name: str, messages: Sequence[tuple], **kw) -> Callable[[Path], Path]:
    """A maker of the bag ``name`` of ``messages`` (``write_raw_bag``) in a dataset."""
    return lambda d: write_raw_bag(d / name, messages, **kw)


def _cases_bad_messages(lab: Lab) -> list[Result]:
    """Readable bags whose messages are malformed, foreign or of another type."""
    out = []
    start = T0 + 10**12
    raw = _raw
    out.append(_bag_case(lab, "bag-lengths-disagree",
                         "a bag whose messages have 2 names and 1 position",
                         raw("bad_lengths", [(start + k * 50 * MS, J2, [0.1], [])
                                             for k in range(20)])))
    out.append(_bag_case(lab, "bag-non-finite", "a bag of NaN and inf positions",
                         raw("bad_nan", [(start + k * 50 * MS, J2,
                                          [np.nan if k % 2 else np.inf, 0.0], [])
                                         for k in range(20)])))
    out.append(_bag_case(lab, "bag-duplicate-joint", "a bag whose messages name j1 twice",
                         raw("bad_dup", [(start + k * 50 * MS, ["j1", "j1"], [0.1, 0.2], [])
                                         for k in range(20)])))
    out.append(_bag_case(lab, "bag-time-backwards", "a bag whose stamps go backwards",
                         raw("bad_backwards", [(start - k * 50 * MS, J2, [0.1, 0.2], [])
                                               for k in range(20)])))
    out.append(_bag_case(lab, "bag-unknown-joints", "a bag of other joints (x1, x2)",
                         raw("bad_foreign", [(start + k * 50 * MS, ["x1", "x2"], [0.1, 0.2],
                                              []) for k in range(20)])))
    out.append(_bag_case(lab, "bag-unknown-joints-selected",
                         "the same bag of x1, x2 with `learn DATASET --joints j1,j2`",
                         raw("bad_foreign", [(start + k * 50 * MS, ["x1", "x2"], [0.1, 0.2],
                                              []) for k in range(20)]),
                         alone=False, extra=("--joints", "j1,j2")))
    out[-1].expect("bad_foreign" in out[-1].data["err"] + out[-1].data["out"],
                   "beside good bags it is not named")
    out.append(_bag_case(lab, "bag-sqlite3", "a valid sqlite3 (.db3) bag (Humble's default)",
                         raw("humble_bag", _good_messages(), storage="sqlite3"),
                         alone=False))
    out.append(_bag_case(lab, "bag-no-joint-state", "a bag with only a std_msgs/String topic",
                         raw("bad_chatter", [(start + k * MS, "hello") for k in range(5)],
                             topic="/chatter", msgtype="std_msgs/msg/String")))
    return out


def _zero_byte(d: Path) -> Path:
    (d / "empty.mcap").write_bytes(b"")
    return d / "empty.mcap"


def _nowhere(d: Path) -> Path:
    bag = d / "bad_nowhere"
    shutil.copytree(d / "demo_0000", bag)
    for f in bag.glob("*.mcap"):
        f.unlink()
    return bag


def _garbage(d: Path) -> Path:
    bag = d / "bad_metadata"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {{{ [not yaml\n")
    return bag


def _truncated(d: Path) -> Path:
    bag = d / "bad_truncated"
    shutil.copytree(d / "demo_0001", bag)
    for f in bag.glob("*.mcap"):
        data = f.read_bytes()
        f.write_bytes(data[: len(data) // 2])
    return bag


def _no_metadata(d: Path) -> Path:
    bag = d / "bad_no_metadata"
    shutil.copytree(d / "demo_0002", bag)
    (bag / "metadata.yaml").unlink()
    return bag


def _no_footer(d: Path) -> Path:
    bag = _no_metadata(d).rename(d / "bad_no_footer")
    for f in bag.glob("*.mcap"):
        data, pos = f.read_bytes(), 8
        while data[pos] != 0x0F:  # walk the records to the Data End record
            pos += 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
        f.write_bytes(data[:pos] + b"\x06\x40")  # and a record cut short
    return bag


def _unfinished(d: Path) -> Path:
    bag = d / ".tmp-demo_0100"
    shutil.copytree(d / "demo_0003", bag)
    for f in bag.glob("*.mcap"):
        f.write_bytes(f.read_bytes()[:100])
    return bag


def _cases_damaged_files(lab: Lab) -> list[Result]:
    """Bag files and directories that are empty, cut short or incomplete."""
    return [
        _bag_case(lab, "bag-zero-byte-mcap", "a zero-byte `empty.mcap`", _zero_byte),
        _bag_case(lab, "bag-metadata-nowhere",
                  "a bag directory whose metadata.yaml names a missing .mcap", _nowhere),
        _bag_case(lab, "bag-metadata-garbage", "a metadata.yaml that is not YAML", _garbage),
        _bag_case(lab, "bag-truncated", "a bag whose .mcap is cut in half", _truncated),
        _bag_case(lab, "bag-no-metadata", "a bag directory with its .mcap but no "
                  "metadata.yaml (as `ros2 bag record` leaves when killed)",
                  _no_metadata, alone_code=None),
        _bag_case(lab, "bag-killed-no-footer", "the same, its .mcap ending in a "
                  "half-written record, with no summary and no footer (`ros2 bag "
                  "record` killed with SIGKILL)", _no_footer, alone_code=None),
        _bag_case(lab, "bag-unfinished-hidden", "a hidden `.tmp-demo_0100` bag (a recorder "
                  "killed mid-write)", _unfinished, alone=False),
    ]


def cases_bags(lab: Lab) -> list[Result]:
    """Bags that are malformed, foreign or broken, each beside good ones and alone."""
    return _cases_bad_messages(lab) + _cases_damaged_files(lab)
