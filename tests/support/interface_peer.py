"""The other process of test_interfaces: publishes a known GraspArray on /peer/grasps
until told to stop, and serves /peer/execute_grasp by echoing the request back."""
import math
import sys

import rclpy
from builtin_interfaces.msg import Duration
from gravgrasp_msgs.msg import Grasp, GraspArray
from gravgrasp_msgs.srv import ExecuteGrasp


def sample_grasp_array() -> GraspArray:
    """A GraspArray with awkward values (non-trivial floats, max uint16) so a lossy
    round trip would show."""
    array = GraspArray()
    array.header.frame_id = "task"
    array.header.stamp.sec, array.header.stamp.nanosec = 1763776800, 123456789
    array.detection_latency = Duration(sec=0, nanosec=9_876_543)
    array.model_name = "gravgrasp-ex-ez.pt"
    for n in range(5):
        g = Grasp()
        g.pose.position.x, g.pose.position.y, g.pose.position.z = 0.0375 * n, 0.15 - 0.01 * n, 0.0525
        half = 0.1 * n
        g.pose.orientation.z, g.pose.orientation.w = math.sin(half), math.cos(half)
        g.gravity_rejection_score = 42.5 - 3.25 * n
        g.validness = 0.99 - 0.1 * n
        g.voxel_index = [n, 39 - n, 65535 if n == 4 else 7]
        g.pregrasp_distance_m = 0.05
        array.grasps.append(g)
    return array


def main():
    rclpy.init()
    node = rclpy.create_node("interface_peer")
    publisher = node.create_publisher(GraspArray, "/peer/grasps", 10)

    def execute(request, response):
        response.success = not request.use_index
        response.result_code = (ExecuteGrasp.Response.SUCCESS if response.success
                                else ExecuteGrasp.Response.INVALID_REQUEST)
        response.message = f"echo frame={request.header.frame_id} index={request.grasp_index}"
        response.executed_grasp = request.grasp
        return response

    node.create_service(ExecuteGrasp, "/peer/execute_grasp", execute)
    node.create_timer(0.1, lambda: publisher.publish(sample_grasp_array()))
    print("interface_peer ready", flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
