"""The executor's client of its ros2_control controller's ``get_parameters`` service, which
``~/enable`` asks for the controller's ``joints`` (the command order check)."""

from __future__ import annotations

from collections.abc import Sequence

from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
from rclpy.exceptions import InvalidServiceNameException, InvalidTopicNameException
from rclpy.expand_topic_name import expand_topic_name
from rclpy.node import Node
from rclpy.validate_full_topic_name import validate_full_topic_name

from policy_align_ros.control import controller_order_refusal, order_check_off
from policy_align_ros.nodes._common import call_with_timeout

__all__ = ["CONTROLLER_TIMEOUT_S", "ControllerClient"]

#: How long ~/enable waits for the controller's joints parameter (s, wall time).
CONTROLLER_TIMEOUT_S = 1.0


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

    def name_problem(self, controller: str) -> str:
        """Why ``controller`` (a parameter value) names no node to ask; empty when it does,
        or turns the check off."""
        if order_check_off(controller):
            return ""
        try:
            self.service(controller)
        except (InvalidServiceNameException, InvalidTopicNameException, ValueError) as err:
            return f"controller: not a valid node name: {controller!r} ({err})"
        return ""

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

    async def order_refusal(self, client, controller: str, joints: Sequence[str]
                            ) -> tuple[str, str]:
        """Compare ``controller``'s ``joints`` parameter with ``joints``, asked through
        ``client`` (the one :meth:`begin` gave, or None), waiting at most
        :data:`CONTROLLER_TIMEOUT_S`.

        Returns
        -------
        (refusal, note)
            ``refusal`` names a mismatch or why the order could not be read (empty: go
            ahead); ``note`` is appended to the ~/enable answer when the check is off.
        """
        if order_check_off(controller) or client is None:
            return "", f"; joint order check off (controller {controller!r})"
        answer = await call_with_timeout(
            client, GetParameters.Request(names=["joints"]), CONTROLLER_TIMEOUT_S)
        value = answer.values[0] if answer is not None and len(answer.values) == 1 else None
        order = (value.string_array_value if value is not None
                 and value.type == ParameterType.PARAMETER_STRING_ARRAY else None)
        return controller_order_refusal(controller, order, joints, answer is not None,
                                        CONTROLLER_TIMEOUT_S), ""

    def _destroy_retired(self) -> None:
        if self._waiting == 0:
            for client in self.retired:
                self.node.destroy_client(client)
            self.retired.clear()
