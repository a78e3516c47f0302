"""
Build helpers for the firmware tests: toolchain (apt when missing), ELF, host programs.

Each helper returns a path or calls ``pytest.skip`` with ONE line saying what is missing
(for example when apt cannot reach its mirrors on an offline machine).
"""

import os
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIRMWARE = os.path.join(ROOT, 'firmware')
ENSURE = os.path.join(FIRMWARE, 'tools', 'ensure-toolchain.sh')
HARNESS_SRC = os.path.join(ROOT, 'test', 'firmware', 'hil', 'mpu_board.c')


def ensure_toolchain(what):
    """Install (or find) the Debian packages for ``what`` ('fw', 'hil' or 'host'), or skip."""
    run = subprocess.run(['sh', ENSURE, what], capture_output=True, text=True, timeout=900)
    if run.returncode != 0:
        lines = [line for line in run.stderr.splitlines() if line.strip()]
        pytest.skip(lines[-1] if lines else f'firmware toolchain ({what}) unavailable')


def _run(cmd, what):
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if run.returncode != 0:
        raise AssertionError(f'{what} failed:\n{run.stdout}\n{run.stderr}')
    return run


def build_firmware(build_dir, **settings):
    """
    Build the firmware with make variables (e.g. ``FW_BAUD=115200``) into ``build_dir``.

    :return: path of the ELF.
    """
    cmd = ['make', '-s', '-C', FIRMWARE, f'BUILD={build_dir}']
    cmd += [f'{k}={v}' for k, v in settings.items()]
    _run(cmd, 'make firmware')
    return os.path.join(str(build_dir), 'accel_calib_fw.elf')


def build_harness(out_dir):
    """Compile the simavr board (GPL-3 test program) into ``out_dir``; return its path."""
    exe = os.path.join(str(out_dir), 'mpu_board')
    flags = subprocess.run(['pkg-config', '--cflags', '--libs', 'simavr'],
                           capture_output=True, text=True).stdout.split() or ['-lsimavr']
    _run(['cc', '-O2', '-o', exe, HARNESS_SRC] + flags + ['-lelf'], 'compiling mpu_board')
    return exe


def build_host_encoder(out_dir):
    """Compile the portable frame encoder with its host test driver; return its path."""
    exe = os.path.join(str(out_dir), 'encode_host')
    _run(['cc', '-std=c99', '-Wall', '-Wextra', '-Werror', '-O2',
          '-I', os.path.join(FIRMWARE, 'src'), '-o', exe,
          os.path.join(FIRMWARE, 'host', 'encode_main.c'),
          os.path.join(FIRMWARE, 'src', 'frame.c')], 'compiling the host encoder')
    return exe
