"""Session-wide test settings: an isolated DDS domain on this host only."""

import importlib.util
import os
import random
import re

import pytest

HAS_ROS = importlib.util.find_spec('rclpy') is not None
NEEDS_ROS = re.compile(r'^(from|import) (rclpy|rcl_interfaces|sensor_msgs|std_msgs|std_srvs|'
                       r'builtin_interfaces|diagnostic_msgs|accel_calib_ros\.nodes|ros_helpers)\b',
                       re.M)


def pytest_ignore_collect(collection_path, config):
    """Without ROS 2 (the Noble venv) leave out the test modules that import it at the top."""
    if HAS_ROS or collection_path.suffix != '.py' or not collection_path.is_file():
        return None
    try:
        text = collection_path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError):
        return None
    return True if NEEDS_ROS.search(text) else None


@pytest.fixture(scope='session', autouse=True)
def ros_isolation():
    """
    Run the whole session in a random ROS_DOMAIN_ID (1..100), discovery on localhost.

    Set before any test creates an rclpy context; subprocesses inherit it.
    """
    keys = ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')
    saved = {k: os.environ.get(k) for k in keys}
    os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(1, 100))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    yield os.environ['ROS_DOMAIN_ID']
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
