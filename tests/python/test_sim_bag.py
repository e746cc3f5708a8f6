"""Bags recorded by `groupforward sim record` read back with rosbags, the independent rosbag2
implementation: every message of every topic deserialises, metadata.yaml agrees with the MCAP
file, and the content matches what the scene file asks for."""

import subprocess
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / 'sim' / 'scenes' / 'office_effects.toml'


def record(binary, out, *extra):
    subprocess.run([str(binary), 'sim', 'record', str(SCENE), '--out', str(out), *extra], check=True,
                   capture_output=True, timeout=300)
    return out


def read_all(bag, ts):
    messages = {}
    with AnyReader([bag], default_typestore=ts) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for connection, _, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            messages.setdefault(connection.topic, []).append(msg)
    return counts, messages


@pytest.fixture(scope='module')
def office(binary, tmp_path_factory, ts):
    bag = record(binary, tmp_path_factory.mktemp('bags') / 'office', '--depth-mm')
    return read_all(bag, ts)


def test_every_message_of_a_recorded_bag_deserialises(office):
    counts, messages = office
    assert set(counts) == {
        '/camera/color/image_raw', '/camera/color/camera_info', '/camera/depth/image_raw', '/tf', '/tf_static',
        '/gt/tf', '/gt/objects', '/gt/camera/depth', '/gt/camera/instance', '/gt/camera/class',
    }
    for topic, count in counts.items():
        assert len(messages[topic]) == count, topic
    frames = len(messages['/tf'])
    assert frames == 45
    kept = len(messages['/camera/color/image_raw'])
    assert 0 < kept < frames, 'frame_drops drops some frames, not all'
    assert len(messages['/camera/depth/image_raw']) == kept == len(messages['/gt/camera/instance'])


def test_recorded_content_follows_the_scene_file(office):
    _, messages = office
    info = messages['/camera/color/camera_info'][0]
    assert info.distortion_model == 'plumb_bob'
    assert np.allclose(info.d, [-0.12, 0.02, 0.0005, -0.0005, 0.0])
    assert (info.width, info.height) == (320, 240)
    depth = messages['/camera/depth/image_raw'][0]
    assert depth.encoding == '16UC1'
    mm = np.frombuffer(depth.data, dtype='<u2')
    assert 0 < np.count_nonzero(mm == 0) < mm.size // 5, 'dropout marks a few pixels invalid'
    objects = messages['/gt/objects'][0]
    assert len(objects.detections) == 11
    classes = sorted(d.results[0].hypothesis.class_id for d in objects.detections)
    assert classes.count('desk') == 2 and classes.count('monitor') == 2
    instance = messages['/gt/camera/instance'][0]
    ids = set(np.frombuffer(instance.data, dtype='<u2').tolist()) - {0}
    assert ids and ids <= {int(d.id) for d in objects.detections}
    # Odometry drifts away from the truth; the stamps of camera messages jitter around /tf's.
    tf, gt = messages['/tf'][-1].transforms[0], messages['/gt/tf'][-1].transforms[0]
    assert tf.header.frame_id == 'map' and tf.child_frame_id == 'base_link'
    assert (tf.transform.translation.x, tf.transform.translation.y) != (gt.transform.translation.x,
                                                                       gt.transform.translation.y)
    image = messages['/camera/color/image_raw'][0]
    assert image.encoding == 'rgb8' and image.header.frame_id == 'camera_color_optical_frame'


def test_compressed_colour_records_as_jpeg(binary, tmp_path, ts):
    bag = record(binary, tmp_path / 'office_jpeg', '--compressed', 'jpeg', '--no-ground-truth')
    counts, messages = read_all(bag, ts)
    assert not any(topic.startswith('/gt/') for topic in counts)
    compressed = messages['/camera/color/image_raw/compressed'][0]
    assert 'jpeg' in compressed.format
    assert bytes(compressed.data[:2]) == b'\xff\xd8'
