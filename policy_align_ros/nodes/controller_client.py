"""The executor's client of its ros2_control controller's ``get_parameters`` service, which
``~/enable`` asks for the controller's ``joints`` (the command order check)."""

from __future__ import annotations

from rcl_interfaces.srv import GetParameters
from rclpy.expand_topic_name import expand_topic_name
from rclpy.node import Node
from rclpy.validate_full_topic_name import validate_full_topic_name

from policy_align_ros.control import order_check_off

__all__ = ["ControllerClient"]


class ControllerClient:
    """The client of the controller in force (``client``; None with the check off), and
    the ones it replaced while an ``~/enable`` check still waited on them (``retired``):
    those are destroyed once no check waits, since a destroyed client raises in the
    coroutine waiting on it.

    Parameters
    ----------
    node : Node
        The executor, which owns the clients.
    """

    def __init__(self, node: Node) -> None:
        self.node = node
        self.client = None
        self.retired: list = []
        self._waiting = 0

    def service(self, controller: str) -> str:
        """Fully qualified name of ``controller``'s get_parameters service; raises what
        rclpy raises for a name that is not valid."""
        name = expand_topic_name(f"{controller}/get_parameters", self.node.get_name(),
                                 self.node.get_namespace())
        validate_full_topic_name(name, is_service=True)
        return name

    def use(self, controller: str) -> None:
        """Ask ``controller`` from now on (none for a ``controller`` that turns the check
        off)."""
        if self.client is not None:
            self.retired.append(self.client)
            self.client = None
            self._destroy_retired()
        if not order_check_off(controller):
            self.client = self.node.create_client(GetParameters, self.service(controller))

    def begin(self):
        """A check begins: the client it waits on (None: check off)."""
        self._waiting += 1
        return self.client

    def end(self) -> None:
        """A check that :meth:`begin` began has ended."""
        self._waiting -= 1
        self._destroy_retired()

    def _destroy_retired(self) -> None:
        if self._waiting == 0:
            for client in self.retired:
                self.node.destroy_client(client)
            self.retired.clear()
