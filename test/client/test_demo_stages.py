"""The demo's stages without a graph (policy_align_ros.client.demo.stages)."""

import pytest

from policy_align_ros.client.demo.settings import DemoSettings, StageError


def test_a_stalled_recording_names_its_wall_time_budget(monkeypatch):
    from policy_align_ros.client.demo import stages

    class Clock:  # each reading 10 s after the one before, from a large monotonic origin
        now = 1e6

        @classmethod
        def monotonic(cls):
            cls.now += 10.0
            return cls.now

    class Proc:
        def poll(self):
            return None

    class Graph:
        procs = {"demonstrator": Proc()}

        def check(self, allow_exit=()):
            pass

        def tail(self, name):
            return ""

    class Conductor:
        progress = ""

        def now(self):
            return 0.0

        def spin(self, seconds):
            pass

    monkeypatch.setattr(stages, "time", Clock)
    s = DemoSettings(demos=3, demo_duration_s=2.0)  # 30 + 3 * (2 + 6) = 54 s
    with pytest.raises(StageError, match=r"\b54 s\b"):
        stages.record_demonstrations(s, 0.0, Graph(), Conductor())
