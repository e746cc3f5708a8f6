"""Fixtures for interoperability tests against independent implementations (eclipse-zenoh, rosbags).

The node under test is the real binary (GROUPFORWARD_BIN, default target/debug/groupforward),
listening on a free loopback port; Python peers connect to it.
"""

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rostypes import typestore  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(os.environ.get('GROUPFORWARD_BIN', ROOT / 'target' / 'debug' / 'groupforward'))


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def wait_until(what, check, timeout=15.0, every=0.05):
    """Poll `check` until it returns a truthy value; fail with `what` after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out waiting for {what}')
        time.sleep(every)


@pytest.fixture(scope='session')
def ts():
    return typestore()


@pytest.fixture(scope='session')
def binary():
    if not BIN.exists():
        pytest.fail(f'{BIN} does not exist: build it with `cargo build -p groupforward-cli` (make test does)')
    return BIN


class Node:
    """A running `groupforward run` process and a zenoh client session connected to it."""

    def __init__(self, binary, tmp_path, depth=False, extra_args=()):
        self.port = free_port()
        self.endpoint = f'tcp/127.0.0.1:{self.port}'
        config = tmp_path / 'node.yaml'
        depth_line = 'depth_topic: /camera/depth/image_raw' if depth else 'depth_topic: null'
        config.write_text(f"""
zenoh:
  mode: peer
  listen: [{self.endpoint}]
  connect: []
status:
  period_secs: 0.1
outputs:
  republish_secs: 0.3
cameras:
  - name: front
    image_topic: /camera/color/image_raw
    camera_info_topic: /camera/color/camera_info
    {depth_line}
""")
        self.log = open(tmp_path / 'node.log', 'w')  # noqa: SIM115
        self.process = subprocess.Popen([str(binary), 'run', '--config', str(config), *extra_args],
                                        stdout=subprocess.PIPE, stderr=self.log, text=True)
        conf = zenoh.Config()
        conf.insert_json5('mode', '"client"')
        conf.insert_json5('connect/endpoints', json.dumps([self.endpoint]))
        conf.insert_json5('scouting/multicast/enabled', 'false')
        self.session = wait_until('the node to accept zenoh connections', lambda: self._try_open(conf))
        wait_until('the JSON API to answer', lambda: self.status(timeout=0.5))

    def _try_open(self, conf):
        if self.process.poll() is not None:
            raise AssertionError(f'node exited early with {self.process.returncode}')
        try:
            return zenoh.open(conf)
        except zenoh.ZError:
            return None

    def status(self, timeout=2.0):
        """The node's status from its JSON API, or None."""
        for reply in self.session.get('groupforward/default/status', timeout=timeout):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_string())
        return None

    def stop(self):
        self.session.close()
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
        self.log.close()


@pytest.fixture
def node(binary, tmp_path):
    running = Node(binary, tmp_path)
    yield running
    running.stop()
