"""
The launch file as a robot integrator meets it: its processes, under a namespace, live.

``launch``/``launch_ros`` are not on PyPI: :mod:`launch_tools` turns the launch file into
the command lines launch_ros would run, and the live test runs them (the installed
executables) against the virtual sensor and reads the ROS graph.
"""

import os
import re
import shutil
import sys
import time

import launch_tools
import pytest
import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LAUNCH = os.path.join(ROOT, 'launch', 'accel_calib.launch.py')
OURS = ('mpu9250_driver', 'accel_calibration', 'accel_correction')
EDITED = {'driver': ('watchdog_s', 0.75), 'calibration': ('target_accuracy', 0.008),
          'correction': ('reload_period_s', 0.3)}
"""A value edited in each config file, unlike the node's own default."""
CONFIG = {'mpu9250_driver': 'driver.yaml', 'accel_calibration': 'calibration.yaml',
          'accel_correction': 'correction.yaml'}


def bin_path(package, executable):
    """Return the path of an executable installed beside this Python (a venv's bin/)."""
    return os.path.join(os.path.dirname(sys.executable), executable)


def share_with_edits(tmp_path):
    """Return a package share folder whose config files carry the values of :data:`EDITED`."""
    share = tmp_path / 'share'
    shutil.copytree(os.path.join(ROOT, 'config'), share / 'config')
    for name, (key, value) in EDITED.items():
        path = share / 'config' / f'{name}.yaml'
        text = path.read_text(encoding='utf-8')
        text, n = re.subn(rf'^(\s+{key}:) .*$', rf'\g<1> {value}', text, flags=re.M)
        assert n == 1, f'{name}.yaml has no single {key}'
        path.write_text(text, encoding='utf-8')
    return str(share)


def test_arguments_and_one_default_port(monkeypatch):
    args = launch_tools.arguments(launch_tools.load_description(LAUNCH, ROOT, monkeypatch))
    for name in ('namespace', 'use_sim_time', 'port', 'frame_id', 'calibration_file',
                 'driver'):
        assert name in args and args[name][1], f'launch argument {name} (with a description)'
    assert args['namespace'][0] == '' and args['use_sim_time'][0] == 'false'
    assert args['frame_id'][0] == 'imu_link' and args['driver'][0] == 'true'
    assert yaml.safe_load(args['calibration_file'][0]) == ''       # the sensor's default
    with open(os.path.join(ROOT, 'config', 'driver.yaml'), encoding='utf-8') as f:
        driver = yaml.safe_load(f)['/**']['ros__parameters']
    with open(os.path.join(ROOT, 'accel_calib_ros', 'nodes', 'driver.py'),
              encoding='utf-8') as f:
        declared = re.search(r"Param\(\s*'port',\s*'([^']*)'", f.read()).group(1)
    assert args['port'][0] == driver['port'] == declared == '/dev/ttyACM0'
    assert driver['frame_id'] == args['frame_id'][0]


@pytest.mark.parametrize('name', ['driver', 'calibration', 'correction'])
def test_config_files_hold_under_any_namespace(name):
    """Keyed ``/**`` alone: a bare node name would not match under a namespace."""
    with open(os.path.join(ROOT, 'config', f'{name}.yaml'), encoding='utf-8') as f:
        data = yaml.safe_load(f)
    assert list(data) == ['/**'] and list(data['/**']) == ['ros__parameters']


def test_command_lines_under_a_namespace(monkeypatch, tmp_path):
    actions = launch_tools.load_description(LAUNCH, ROOT, monkeypatch)
    procs = launch_tools.command_lines(
        actions, {'namespace': 'robot1', 'port': '/dev/ttyUSB3', 'frame_id': 'robot1/imu',
                  'use_sim_time': 'true'}, str(tmp_path), bin_path)
    assert [p['name'] for p in procs] == list(OURS)          # madgwick is off by default
    for p in procs:
        cmd = p['cmd']
        assert cmd[1:6] == ['--ros-args', '-r', f'__node:={p["name"]}', '-r', '__ns:=/robot1']
        assert p['parameter_files'][0] == os.path.join(ROOT, 'config', CONFIG[p['name']])
        with open(p['parameter_files'][-1], encoding='utf-8') as f:
            (key, body), = yaml.safe_load(f).items()
        assert key == f'/robot1/{p["name"]}'
        assert body['ros__parameters']['frame_id'] == 'robot1/imu'      # one sensor
        # The driver's stamps are the device clock on wall time: never /clock.
        assert body['ros__parameters'].get('use_sim_time') is (
            None if p['name'] == 'mpu9250_driver' else True)
        if p['name'] != 'mpu9250_driver':
            assert body['ros__parameters']['calibration_file'] == ''    # per sensor
    driver = yaml.safe_load(open(procs[0]['parameter_files'][-1], encoding='utf-8'))
    assert driver['/robot1/mpu9250_driver']['ros__parameters'] == {
        'port': '/dev/ttyUSB3', 'frame_id': 'robot1/imu'}
    # Without a namespace: no __ns remap, the nodes at the root.
    root = launch_tools.command_lines(actions, {}, str(tmp_path), bin_path)
    assert all('__ns:=' not in ' '.join(p['cmd']) for p in root)


def test_madgwick_chain_reads_the_corrected_stream(monkeypatch, tmp_path):
    actions = launch_tools.load_description(LAUNCH, ROOT, monkeypatch)
    procs = launch_tools.command_lines(
        actions, {'chain_madgwick': 'true', 'use_mag': 'true', 'namespace': 'r2'},
        str(tmp_path), bin_path)
    madgwick, = [p for p in procs if p['package'] == 'imu_filter_madgwick']
    cmd = ' '.join(madgwick['cmd'])
    assert '-r imu_filter:imu/data_raw:=imu/corrected' in cmd
    assert '-r imu_filter:imu/mag:=imu/mag_corrected' in cmd
    assert '__ns:=/r2' in cmd
    with open(madgwick['parameter_files'][0], encoding='utf-8') as f:
        params = yaml.safe_load(f)['/r2/imu_filter']['ros__parameters']
    assert params['use_mag'] is True and params['world_frame'] == 'enu'
    assert params['publish_tf'] is False
    off = launch_tools.command_lines(actions, {'calibrate': 'false'}, str(tmp_path), bin_path)
    assert [p['name'] for p in off] == ['mpu9250_driver', 'accel_correction']


def test_for_a_bag_or_a_simulator_the_driver_stays_out(monkeypatch, tmp_path):
    actions = launch_tools.load_description(LAUNCH, ROOT, monkeypatch)
    procs = launch_tools.command_lines(
        actions, {'driver': 'false', 'use_sim_time': 'true', 'namespace': 'sim'},
        str(tmp_path), bin_path)
    assert [p['name'] for p in procs] == ['accel_calibration', 'accel_correction']
    for p in procs:
        with open(p['parameter_files'][-1], encoding='utf-8') as f:
            assert yaml.safe_load(f)[f'/sim/{p["name"]}']['ros__parameters'][
                'use_sim_time'] is True


def _graph_and_parameters(collector, wanted, timeout):
    """Spin until every node of ``wanted`` is seen; return the graph and their values."""
    from rcl_interfaces.srv import GetParameters
    import rclpy
    node = collector.node
    deadline = time.monotonic() + timeout
    graph = []
    while time.monotonic() < deadline:
        graph = node.get_node_names_and_namespaces()
        if all((n, '/robot1') in graph for n in wanted):
            break
        collector.spin(0.2)
    values = {}
    for name, (key, _) in wanted.items():
        client = node.create_client(GetParameters, f'/robot1/{name}/get_parameters')
        assert client.wait_for_service(timeout_sec=10.0), f'{name}: no parameter service'
        future = client.call_async(GetParameters.Request(names=[key]))
        rclpy.spin_until_future_complete(node, future, executor=collector.executor,
                                         timeout_sec=10.0)
        assert future.done(), f'{name}: get_parameters did not answer'
        values[name] = future.result().values[0].double_value
        node.destroy_client(client)
    return node.get_node_names_and_namespaces(), values


@pytest.mark.ros
def test_the_launched_graph_under_a_namespace(monkeypatch, tmp_path):
    """Every node once, under /robot1, with the edited config values in force."""
    from ros_helpers import Collector, Processes, read_log
    import subprocess
    share = share_with_edits(tmp_path)
    actions = launch_tools.load_description(LAUNCH, share, monkeypatch)
    procs = Processes(tmp_path)
    started = []
    try:
        _, port = procs.device(['--rate', '200'])
        lines = launch_tools.command_lines(
            actions, {'namespace': 'robot1', 'port': port,
                      'calibration_file': str(tmp_path / 'calibration.yaml')},
            str(tmp_path), bin_path)
        for p in lines:
            log = open(tmp_path / f'{p["name"]}.log', 'w')
            proc = subprocess.Popen(p['cmd'], stdout=log, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL)
            proc.log_path = log.name
            log.close()
            procs.procs.append(proc)
            started.append(proc)
        wanted = {'mpu9250_driver': EDITED['driver'],
                  'accel_calibration': EDITED['calibration'],
                  'accel_correction': EDITED['correction']}
        with Collector({}) as collector:
            graph, values = _graph_and_parameters(collector, wanted, 30.0)
            collector.spin(1.0)                  # any second node would be discovered too
            graph = collector.node.get_node_names_and_namespaces()
        logs = '\n'.join(read_log(p) for p in started)
        ours = sorted((n, ns) for n, ns in graph if ns.startswith('/robot1'))
        assert ours == sorted((n, '/robot1') for n in OURS), (graph, logs[-3000:])
        for name, (_, value) in wanted.items():
            assert values[name] == pytest.approx(value), f'{name}: the edited value is lost'
        assert 'already registered' not in logs and 'Traceback' not in logs
        assert all(p.poll() is None for p in started), logs[-3000:]
    finally:
        procs.stop_all()
