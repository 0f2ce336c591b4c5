"""A separate process serving move_to_pose that accepts a motion and never finishes it:
an arm adapter that hangs mid-move. test_execute_node stops this process to make the
arm service leave the ROS graph while the executor waits on it."""
import os
import threading

import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup

from gravgrasp_detector.ros.interface import spin
from gravgrasp_msgs.srv import MoveToPose


def main():
    rclpy.init()
    node = rclpy.create_node("hanging_arm")
    never = threading.Event()

    def move(request, response):
        print("hanging_arm: motion accepted, never finishing", flush=True)
        never.wait()
        return response

    node.create_service(MoveToPose, "move_to_pose", move, callback_group=ReentrantCallbackGroup())
    print("hanging_arm ready", flush=True)
    # Leave the graph without answering the motion in flight (an adapter that is stopped
    # mid-move; a killed one is noticed only when DDS's participant lease runs out, 20 s
    # with Fast DDS's defaults, so arm_timeout_s bounds that case); os._exit, because the
    # callback thread that never returns would keep the interpreter from exiting.
    try:
        spin([node], threads=2)
    finally:
        os._exit(0)


if __name__ == "__main__":
    main()
