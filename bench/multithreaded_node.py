"""
The executor design not taken, for the benchmarks: a node spun by a MultiThreadedExecutor.

``nodes.spinning`` runs a node with two single-threaded executors (its stream group alone
on one, the rest on another). The alternative on rclpy's public API is one
MultiThreadedExecutor over all the node's callback groups (the stream group mutually
exclusive, the rest as the node declares them). bench/bench_calibration_node.py and
bench/bench_correction.py run the node this way with ``--executor multi``::

    python bench/multithreaded_node.py calibration --ros-args -p ...
"""

import sys


def main():
    """Build the node named by argv[1] and spin it on a MultiThreadedExecutor until SIGINT."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
    kind = sys.argv[1]
    rclpy.init(args=sys.argv)
    if kind == 'calibration':
        from accel_calib_ros.nodes.calibration import CalibrationNode as node_class
    else:
        from accel_calib_ros.nodes.correction import CorrectionNode as node_class
    node = node_class()
    executor = MultiThreadedExecutor(num_threads=3)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown(timeout_sec=2.0)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
