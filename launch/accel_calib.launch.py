"""
Start the MPU9250 driver, the calibration node and the correction node.

Usage::

    ros2 launch accel_calib_ros accel_calib.launch.py port:=/dev/ttyACM0
    ros2 launch accel_calib_ros accel_calib.launch.py namespace:=robot1 frame_id:=robot1/imu_link
    ros2 launch accel_calib_ros accel_calib.launch.py calibration_file:=/data/imu.yaml
    ros2 launch accel_calib_ros accel_calib.launch.py calibrate:=false chain_madgwick:=true
    ros2 launch accel_calib_ros accel_calib.launch.py chain_madgwick:=true use_mag:=true
    ros2 launch accel_calib_ros accel_calib.launch.py driver:=false use_sim_time:=true

Each node is its own process and reads its parameter file from this package's
``config/`` directory (keyed ``/**``, so the values hold under any namespace or node
name); the ``port``, ``frame_id``, ``calibration_file``, ``method`` and ``use_sim_time``
arguments override the values there. ``namespace`` puts every node and topic under it
(``/robot1/imu/data_raw``, ``/robot1/accel_calibration/calibrate``, ...): one launch
per robot. Then hold the sensor still in varied orientations (follow
``accel_calibration/advice``), call ``accel_calibration/calibrate`` and read the
corrected stream on ``imu/corrected``.

One sensor, one calibration: the namespace and ``frame_id`` name the sensor
(``robot1/imu_link``); by default its calibration and history live in
``$ROS_HOME/accel_calib_ros/robot1/imu_link/``, so two launches on one host (two
robots, or two IMUs with two frame_ids) never share a file, and the correction node
refuses a file made for another sensor.

For a bag or a simulator: ``driver:=false`` leaves the driver out (``imu/data_raw``
comes from the bag or the simulator) and ``use_sim_time:=true`` puts the calibration and
correction nodes (and imu_filter_madgwick) on ``/clock``. The driver never takes
``use_sim_time``: its stamps are the device clock mapped onto wall time.

``chain_madgwick:=true`` adds imu_filter_madgwick (``apt install
ros-jazzy-imu-filter-madgwick``) on the corrected stream: its input ``imu/data_raw`` is
remapped to ``imu/corrected``, so it fuses the calibrated acceleration and the
calibrated angular rate and publishes the orientation on ``imu/data`` (ENU world frame,
no TF unless ``madgwick_publish_tf:=true``). With ``use_mag:=true`` it also fuses the
magnetometer: its input ``imu/mag`` is remapped to ``imu/mag_corrected`` (published by
the correction node once the calibration has a magnetometer part), which gives the
orientation an absolute heading; without it (the default) the heading drifts.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'accel_calib_ros'
DEFAULT_PORT = '/dev/ttyACM0'
"""The Arduino Uno's USB serial port (its CDC-ACM chip); the driver's default too."""


def generate_launch_description():
    """Build the launch description (no side effects at import time)."""
    config = os.path.join(get_package_share_directory(PACKAGE), 'config')
    arg = LaunchConfiguration
    namespace = arg('namespace')
    use_sim_time = arg('use_sim_time')
    calibration_file = arg('calibration_file')
    frame_id = arg('frame_id')
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of every node and topic (one per robot)'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='the calibration and correction nodes take time '
                                          'from /clock (a bag or a simulator; the driver '
                                          'never does: device clock on wall time)'),
        DeclareLaunchArgument('driver', default_value='true',
                              description='start the serial driver (false: imu/data_raw '
                                          'comes from a bag or a simulator)'),
        DeclareLaunchArgument('port', default_value=DEFAULT_PORT,
                              description='serial port of the MPU9250 microcontroller'),
        DeclareLaunchArgument('frame_id', default_value='imu_link',
                              description='frame_id of the IMU messages (the URDF link); '
                                          'with the namespace it names the sensor'),
        DeclareLaunchArgument('calibration_file', default_value="''",
                              description="calibration YAML written and applied ('' = the "
                                          "sensor's: $ROS_HOME/accel_calib_ros/<namespace>/"
                                          '<frame_id>/calibration.yaml)'),
        DeclareLaunchArgument('method', default_value='ml',
                              description='calibration solver: ml, gn or ml-bc'),
        DeclareLaunchArgument('calibrate', default_value='true',
                              description='start the accel_calibration node'),
        DeclareLaunchArgument('chain_madgwick', default_value='false',
                              description='run imu_filter_madgwick on imu/corrected '
                                          '(orientation on imu/data)'),
        DeclareLaunchArgument('madgwick_publish_tf', default_value='false',
                              description='let imu_filter_madgwick publish a TF'),
        DeclareLaunchArgument('use_mag', default_value='false',
                              description='imu_filter_madgwick fuses imu/mag_corrected too '
                                          '(needs a magnetometer calibration)'),
        Node(package=PACKAGE, executable='mpu9250_driver', name='mpu9250_driver',
             namespace=namespace, output='screen', emulate_tty=True,
             condition=IfCondition(arg('driver')),
             parameters=[os.path.join(config, 'driver.yaml'),
                         {'port': arg('port'), 'frame_id': frame_id}]),
        Node(package=PACKAGE, executable='accel_calibration', name='accel_calibration',
             namespace=namespace, output='screen', emulate_tty=True,
             condition=IfCondition(arg('calibrate')),
             parameters=[os.path.join(config, 'calibration.yaml'),
                         {'calibration_file': calibration_file, 'method': arg('method'),
                          'frame_id': frame_id, 'use_sim_time': use_sim_time}]),
        Node(package=PACKAGE, executable='accel_correction', name='accel_correction',
             namespace=namespace, output='screen', emulate_tty=True,
             parameters=[os.path.join(config, 'correction.yaml'),
                         {'calibration_file': calibration_file, 'frame_id': frame_id,
                          'use_sim_time': use_sim_time}]),
        Node(package='imu_filter_madgwick', executable='imu_filter_madgwick_node',
             name='imu_filter', namespace=namespace, output='screen', emulate_tty=True,
             condition=IfCondition(arg('chain_madgwick')),
             remappings=[('imu/data_raw', 'imu/corrected'), ('imu/mag', 'imu/mag_corrected')],
             parameters=[{'use_mag': arg('use_mag'), 'world_frame': 'enu',
                          'publish_tf': arg('madgwick_publish_tf'),
                          'use_sim_time': use_sim_time}]),
    ])
