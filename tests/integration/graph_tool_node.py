"""A small node with one of everything `scripts/graph.py` inspects (run by test_graph_tool.py).

Publishes /graph_test/chatter (std_msgs/String, reliable, 20 Hz) and /graph_test/blob
(std_msgs/UInt8MultiArray of 1000 bytes, best effort), serves /graph_test/set_flag
(std_srvs/SetBool) and the action /graph_test/move (tsrrt_interfaces FollowJointTrajectory), and
declares the parameters `greeting` and `rate_hz`.
"""

from __future__ import annotations

import rclpy
from rclpy.action import ActionServer
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import String, UInt8MultiArray
from std_srvs.srv import SetBool

from tsrrt_interfaces.action import FollowJointTrajectory

BLOB_SIZE = 1000


class GraphToolTestNode(Node):
    def __init__(self) -> None:
        super().__init__("graph_tool_test")
        self.greeting = self.declare_parameter("greeting", "hello").value
        rate_hz = self.declare_parameter("rate_hz", 20.0).value
        self.chatter = self.create_publisher(String, "/graph_test/chatter", 10)
        self.blob = self.create_publisher(UInt8MultiArray, "/graph_test/blob",
                                          qos_profile_sensor_data)
        self.create_service(SetBool, "/graph_test/set_flag", self.on_set_flag)
        self.action_server = ActionServer(self, FollowJointTrajectory, "/graph_test/move",
                                          execute_callback=self.on_goal)
        self.count = 0
        self.create_timer(1.0 / rate_hz, self.publish)

    def publish(self) -> None:
        self.count += 1
        self.chatter.publish(String(data=f"{self.greeting} {self.count}"))
        self.blob.publish(UInt8MultiArray(data=[i % 256 for i in range(BLOB_SIZE)]))

    def on_set_flag(self, request: SetBool.Request,
                    response: SetBool.Response) -> SetBool.Response:
        response.success = True
        response.message = f"flag is now {request.data}"
        return response

    def on_goal(self, goal_handle) -> FollowJointTrajectory.Result:
        goal_handle.succeed()
        return FollowJointTrajectory.Result()


def main() -> None:
    rclpy.init()
    node = GraphToolTestNode()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
