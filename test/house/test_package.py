"""
The package as a robot gets it: every dependency named, a licence, a colcon install.

package.xml names every dependency, the LICENSE matches it, and a ``colcon build``
installs what ``ros2 run`` and ``ros2 launch`` look for.
"""

import ast
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest
from test_layout import parse

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PACKAGE = 'accel_calib_ros'
EXECUTABLES = ('mpu9250_driver', 'accel_calibration', 'accel_correction', 'accel-calib')
ROSDEP = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
          'serial': 'python3-serial', 'matplotlib': 'python3-matplotlib',
          'tqdm': 'python3-tqdm', 'rich': 'python3-rich', 'rosbags': 'python3-rosbags-pip',
          'hypothesis': 'python3-hypothesis', 'pytest': 'python3-pytest'}
"""Python module -> rosdep key; a ROS package's module has the package's own name."""
SOURCES = ('accel_calib_ros', 'launch', 'config', 'resource', 'package.xml', 'setup.py',
           'setup.cfg', 'README.md', 'LICENSE')


def depends():
    """Return {tag: set of keys} of package.xml (exec_depend, test_depend, ...)."""
    out = {}
    for element in ET.parse(os.path.join(ROOT, 'package.xml')).getroot():
        if element.tag.endswith('depend'):
            out.setdefault(element.tag, set()).add(element.text.strip())
    return out


def third_party_imports(folder):
    """Return the top-level modules ``folder``'s Python files import, but ours and stdlib."""
    local = {os.path.splitext(f)[0] for top in (folder, 'bench')     # tests use bench/ too
             for _, _, files in os.walk(os.path.join(ROOT, top)) for f in files
             if f.endswith('.py')}
    found = set()
    for path, _, files in os.walk(os.path.join(ROOT, folder)):
        for name in files:
            if not name.endswith('.py'):
                continue
            for node in ast.walk(parse(os.path.join(path, name))):
                if isinstance(node, ast.Import):
                    found.update(a.name.split('.')[0] for a in node.names)
                elif isinstance(node, ast.ImportFrom) and not node.level:
                    found.add(node.module.split('.')[0])
    return found - set(sys.stdlib_module_names) - local - {PACKAGE}


@pytest.mark.parametrize('folder, tags', [
    ('accel_calib_ros', ('exec_depend', 'depend')),
    ('launch', ('exec_depend', 'depend')),
    ('test', ('test_depend', 'exec_depend', 'depend')),
])
def test_every_import_has_a_depend(folder, tags):
    declared = set().union(*(depends().get(t, set()) for t in tags))
    missing = sorted(m for m in third_party_imports(folder) if ROSDEP.get(m, m) not in declared)
    assert missing == [], f'{folder}/ imports without a {"/".join(tags)}: {missing}'


def test_licence_matches_package_xml():
    license_ = ET.parse(os.path.join(ROOT, 'package.xml')).getroot().find('license').text
    assert license_ == 'BSD-3-Clause'
    with open(os.path.join(ROOT, 'LICENSE'), encoding='utf-8') as f:
        text = f.read()
    assert text.startswith('BSD 3-Clause License')
    assert 'Neither the name of the copyright holder' in text


def test_colcon_build_installs_what_ros2_run_and_launch_find(tmp_path):
    """``colcon build`` of a copy of the package: executables, launch/, config/, index."""
    colcon = shutil.which('colcon', path=os.path.dirname(sys.executable))
    assert colcon, 'colcon is installed by requirements-dev.txt (colcon-core, colcon-ros)'
    src = tmp_path / 'src' / PACKAGE
    for name in SOURCES:
        source = os.path.join(ROOT, name)
        if os.path.isdir(source):
            shutil.copytree(source, src / name,
                            ignore=shutil.ignore_patterns('__pycache__', '*.egg-info'))
        else:
            os.makedirs(src, exist_ok=True)
            shutil.copy2(source, src / name)
    run = subprocess.run(
        [colcon, '--log-base', str(tmp_path / 'log'), 'build', '--base-paths',
         str(tmp_path / 'src'), '--build-base', str(tmp_path / 'build'),
         '--install-base', str(tmp_path / 'install')],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert 'Finished <<< accel_calib_ros' in run.stdout, run.stdout[-3000:]
    prefix = tmp_path / 'install' / PACKAGE
    # ros2 run: <prefix>/lib/<package>/<executable>, found through the ament index.
    from ament_index_python.packages import get_package_prefix, get_package_share_directory
    old = os.environ.get('AMENT_PREFIX_PATH')
    os.environ['AMENT_PREFIX_PATH'] = str(prefix)
    try:
        assert get_package_prefix(PACKAGE) == str(prefix)
        share = get_package_share_directory(PACKAGE)
    finally:
        if old is None:
            del os.environ['AMENT_PREFIX_PATH']
        else:
            os.environ['AMENT_PREFIX_PATH'] = old
    for exe in EXECUTABLES:
        path = prefix / 'lib' / PACKAGE / exe
        assert path.is_file() and os.access(path, os.X_OK), f'ros2 run finds no {exe}'
    for rel in ('package.xml', 'launch/accel_calib.launch.py', 'config/driver.yaml',
                'config/calibration.yaml', 'config/correction.yaml'):
        assert os.path.isfile(os.path.join(share, rel)), f'share/{PACKAGE}/{rel} missing'
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()
    # The installed command runs from the install space, not from this checkout.
    site = [str(p) for p in (prefix / 'lib').glob('python3*/site-packages')]
    assert site, 'no site-packages in the install space'
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join(site)}
    out = subprocess.run([str(prefix / 'lib' / PACKAGE / 'accel-calib'), '--help'],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and 'usage: accel-calib' in out.stdout, out.stderr[-2000:]
    where = subprocess.run(
        [sys.executable, '-c', 'import accel_calib_ros, sys; print(accel_calib_ros.__file__)'],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert where.stdout.strip().startswith(str(prefix)), where.stdout + where.stderr
