"""ament_python / pip install script for accel_calib_ros."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'accel_calib_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'bench']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'LICENSE']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    python_requires='>=3.10',
    # Only setuptools here, as ROS packages do: on a robot the Python dependencies come
    # from rosdep (package.xml); in a venv from requirements.txt (see the Makefile).
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='accel_calib_ros maintainers',
    maintainer_email='maintainers@accel-calib.dev',
    description='MEMS triaxial accelerometer calibration and live correction for ROS 2',
    license='BSD-3-Clause',
    extras_require={'test': ['pytest']},
    entry_points={
        'console_scripts': [
            'mpu9250_driver = accel_calib_ros.nodes.driver:main',
            'accel_calibration = accel_calib_ros.nodes.calibration:main',
            'accel_correction = accel_calib_ros.nodes.correction:main',
            'accel-calib = accel_calib_ros.cli:main',
        ],
    },
)
