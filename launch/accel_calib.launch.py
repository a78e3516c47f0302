"""
Start the MPU9250 driver, the calibration node and the correction node.

Usage::

    ros2 launch accel_calib_ros accel_calib.launch.py port:=/dev/ttyACM0
    ros2 launch accel_calib_ros accel_calib.launch.py calibration_file:=/data/imu.yaml
    ros2 launch accel_calib_ros accel_calib.launch.py calibrate:=false chain_madgwick:=true
    ros2 launch accel_calib_ros accel_calib.launch.py chain_madgwick:=true use_mag:=true

Each node reads its parameter file from this package's ``config/`` directory; the
``port`` and ``calibration_file`` arguments override the values there. Then hold the
sensor still in varied orientations (follow ``/accel_calibration/advice``), call
``/accel_calibration/calibrate`` and read the corrected stream on ``imu/corrected``.

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


def generate_launch_description():
    """Build the launch description (no side effects at import time)."""
    config = os.path.join(get_package_share_directory(PACKAGE), 'config')
    port = LaunchConfiguration('port')
    calibration_file = LaunchConfiguration('calibration_file')
    method = LaunchConfiguration('method')
    default_file = os.path.join(
        os.environ.get('ROS_HOME', os.path.join(os.path.expanduser('~'), '.ros')),
        PACKAGE, 'calibration.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('port', default_value='/dev/ttyACM0',
                              description='serial port of the MPU9250 microcontroller'),
        DeclareLaunchArgument('calibration_file', default_value=default_file,
                              description='calibration YAML written and applied'),
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
             output='screen', emulate_tty=True,
             parameters=[os.path.join(config, 'driver.yaml'), {'port': port}]),
        Node(package=PACKAGE, executable='accel_calibration', name='accel_calibration',
             output='screen', emulate_tty=True,
             condition=IfCondition(LaunchConfiguration('calibrate')),
             parameters=[os.path.join(config, 'calibration.yaml'),
                         {'calibration_file': calibration_file, 'method': method}]),
        Node(package=PACKAGE, executable='accel_correction', name='accel_correction',
             output='screen', emulate_tty=True,
             parameters=[os.path.join(config, 'correction.yaml'),
                         {'calibration_file': calibration_file}]),
        Node(package='imu_filter_madgwick', executable='imu_filter_madgwick_node',
             name='imu_filter', output='screen', emulate_tty=True,
             condition=IfCondition(LaunchConfiguration('chain_madgwick')),
             remappings=[('imu/data_raw', 'imu/corrected'), ('imu/mag', 'imu/mag_corrected')],
             parameters=[{'use_mag': LaunchConfiguration('use_mag'), 'world_frame': 'enu',
                          'publish_tf': LaunchConfiguration('madgwick_publish_tf')}]),
    ])
