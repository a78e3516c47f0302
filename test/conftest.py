"""Session-wide test settings: an isolated DDS domain on this host only."""

import os
import random

import pytest


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
