"""A node's log kept for the tests: the node class with its logger replaced by one that
records ``(severity, message)`` pairs in ``node.log.records``."""

from __future__ import annotations


class RecordedLog:
    """A logger standing in for the node's: (severity, message) records."""

    def __init__(self) -> None:
        self.records: list[tuple[str, str]] = []

    def __getattr__(self, severity: str):
        return lambda message, **_: self.records.append((severity, str(message)))


def logged(node_class: type) -> type:
    """``node_class`` with its log records kept (``node.log.records``)."""

    class Logged(node_class):
        def get_logger(self):
            if not hasattr(self, "log"):
                self.log = RecordedLog()
            return self.log

    Logged.__name__ = Logged.__qualname__ = f"Logged{node_class.__name__}"
    return Logged
