"""Write golden CDR vectors and RIHS01 hashes with an independent implementation (Python rosbags).

Run from the repository root:  .venv/bin/python msgs/tests/golden/make_golden.py
Writes msgs/tests/golden/golden.json: for each case, the rosbags-encoded CDR bytes (hex) and the
message as plain JSON; for each type, rosbags' RIHS01 hash. The Rust test decodes every vector,
compares it with the JSON, re-encodes it and compares the bytes.
"""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'tests' / 'python'))
from rostypes import typestore  # noqa: E402

OUT = Path(__file__).resolve().parent / 'golden.json'

ts = typestore()
add = {name: None for name in ts.types if name.startswith(('vision_msgs/', 'groupforward_msgs/'))}

T = lambda name: ts.types[name]  # noqa: E731
Time = T('builtin_interfaces/msg/Time')
Duration = T('builtin_interfaces/msg/Duration')
Header = T('std_msgs/msg/Header')
Point = T('geometry_msgs/msg/Point')
Vector3 = T('geometry_msgs/msg/Vector3')
Quaternion = T('geometry_msgs/msg/Quaternion')
Pose = T('geometry_msgs/msg/Pose')


def header(sec, frame):
    return Header(stamp=Time(sec=sec, nanosec=123456789), frame_id=frame)


def pose(x):
    return Pose(position=Point(x=x, y=-2.5, z=0.125), orientation=Quaternion(x=0.0, y=0.0, z=0.5, w=0.75))


def u8(values):
    return np.array(values, dtype=np.uint8)


hyp = T('vision_msgs/msg/ObjectHypothesis')(class_id='trash bin', score=0.875)
box = T('vision_msgs/msg/BoundingBox3D')(center=pose(1.0), size=Vector3(x=0.5, y=0.25, z=1.0))
transform = T('geometry_msgs/msg/TransformStamped')(
    header=header(5, 'map'), child_frame_id='base_link',
    transform=T('geometry_msgs/msg/Transform')(translation=Vector3(x=1.0, y=2.0, z=3.0),
                                               rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)))
image = T('sensor_msgs/msg/Image')(header=header(1, 'cam0_optical'), height=2, width=3, encoding='rgb8',
                                   is_bigendian=0, step=9, data=u8(range(18)))
instance = T('groupforward_msgs/msg/Instance')(
    id='chair_3', hypotheses=[hyp], pose=pose(3.0), size=Vector3(x=0.5, y=0.5, z=0.9), point_count=4096,
    visibility=0.5, confidence=0.75, first_seen=Time(sec=1, nanosec=0), last_seen=Time(sec=9, nanosec=5))
masks = T('groupforward_msgs/msg/InstanceMasks')(header=header(4, 'cam0_optical'), camera='front', mask=image,
                                                  instance_ids=['chair_3', 'table_1'])
node = T('groupforward_msgs/msg/SceneGraphNode')(
    id='chair_3', label='chair', prototype=np.array([0.5, -0.25, 0.0], dtype=np.float32), center=Point(x=1.0, y=2.0, z=0.5),
    extent=Vector3(x=0.5, y=0.5, z=0.9), volume=0.225,
    views=[T('groupforward_msgs/msg/NodeView')(keyframe_id='kf_0', x_min=1.0, y_min=2.0, x_max=30.5, y_max=40.25,
                                               visibility=0.75)])
edge = T('groupforward_msgs/msg/SceneGraphEdge')(
    source='chair_3', target='table_1', distance=1.5, height_difference=-0.25, size_ratio=2.0,
    views=[T('groupforward_msgs/msg/EdgeView')(keyframe_id='kf_0', projected_distance=12.5, direction=-1.5,
                                               overlap=0.25)])
cloud = T('sensor_msgs/msg/PointCloud2')(
    header=header(2, 'map'), height=1, width=2,
    fields=[T('sensor_msgs/msg/PointField')(name='x', offset=0, datatype=7, count=1),
            T('sensor_msgs/msg/PointField')(name='instance_id', offset=4, datatype=6, count=1)],
    is_bigendian=False, point_step=8, row_step=16, data=u8(range(16)), is_dense=True)
candidate = T('groupforward_msgs/msg/Candidate')(id='chair_3', label='chair', score=0.75, semantic_score=0.5,
                                                 geometric_score=1.0, visibility_score=0.25)

cases = [
    ('builtin_interfaces/msg/Time', Time(sec=-3, nanosec=999)),
    ('std_msgs/msg/Header', header(7, 'odom')),
    ('sensor_msgs/msg/Image', image),
    ('sensor_msgs/msg/CompressedImage', T('sensor_msgs/msg/CompressedImage')(header=header(1, 'c'), format='jpeg',
                                                                             data=u8([255, 216, 255, 1, 2]))),
    ('sensor_msgs/msg/CameraInfo', T('sensor_msgs/msg/CameraInfo')(
        header=header(1, 'cam0_optical'), height=480, width=640, distortion_model='plumb_bob',
        d=np.array([0.1, -0.2, 0.001, 0.002, 0.0]),
        k=np.array([500.0, 0, 320, 0, 500, 240, 0, 0, 1]), r=np.eye(3).flatten(),
        p=np.array([500.0, 0, 320, 0, 0, 500, 240, 0, 0, 0, 1, 0]), binning_x=0, binning_y=0,
        roi=T('sensor_msgs/msg/RegionOfInterest')(x_offset=1, y_offset=2, height=3, width=4, do_rectify=True))),
    ('sensor_msgs/msg/PointCloud2', cloud),
    ('geometry_msgs/msg/TransformStamped', transform),
    ('tf2_msgs/msg/TFMessage', T('tf2_msgs/msg/TFMessage')(transforms=[transform, transform])),
    ('geometry_msgs/msg/Pose', pose(4.0)),
    ('vision_msgs/msg/Detection3DArray', T('vision_msgs/msg/Detection3DArray')(
        header=header(3, 'map'),
        detections=[T('vision_msgs/msg/Detection3D')(
            header=header(3, 'map'),
            results=[T('vision_msgs/msg/ObjectHypothesisWithPose')(
                hypothesis=hyp,
                pose=T('geometry_msgs/msg/PoseWithCovariance')(pose=pose(1.0), covariance=np.arange(36, dtype=np.float64)))],
            bbox=box, id='trash_bin_2')])),
    ('visualization_msgs/msg/MarkerArray', T('visualization_msgs/msg/MarkerArray')(markers=[T('visualization_msgs/msg/Marker')(
        header=header(3, 'map'), ns='instances', id=4, type=1, action=0, pose=pose(2.0), scale=Vector3(x=1.0, y=1.0, z=1.0),
        color=T('std_msgs/msg/ColorRGBA')(r=1.0, g=0.5, b=0.25, a=1.0), lifetime=Duration(sec=0, nanosec=0),
        frame_locked=False, points=[Point(x=1.0, y=2.0, z=3.0)], colors=[], texture_resource='',
        texture=T('sensor_msgs/msg/CompressedImage')(header=header(0, ''), format='', data=u8([])),
        uv_coordinates=[T('visualization_msgs/msg/UVCoordinate')(u=0.5, v=0.25)], text='chair',
        mesh_resource='', mesh_file=T('visualization_msgs/msg/MeshFile')(filename='', data=u8([7])),
        mesh_use_embedded_materials=False)])),
    ('groupforward_msgs/msg/InstanceArray', T('groupforward_msgs/msg/InstanceArray')(header=header(9, 'map'),
                                                                                    instances=[instance, instance])),
    ('groupforward_msgs/msg/InstanceMasks', masks),
    ('groupforward_msgs/msg/SceneGraph', T('groupforward_msgs/msg/SceneGraph')(header=header(9, 'map'), nodes=[node],
                                                                              edges=[edge])),
    ('groupforward_msgs/msg/NodeStatus', T('groupforward_msgs/msg/NodeStatus')(
        header=header(9, ''), uptime_secs=12.5,
        cameras=[T('groupforward_msgs/msg/CameraStatus')(name='front', frames_received=10, frames_synced=9,
                                                         frames_rejected=1, rate_hz=29.5, last_stamp=Time(sec=9, nanosec=1),
                                                         depth_pixels=76800, depth_pixels_invalid=4321)],
        tf_received=100, tf_rejected=2,
        rejections=[T('groupforward_msgs/msg/RejectCount')(reason='size_mismatch', count=1)],
        stages=[T('groupforward_msgs/msg/StageTiming')(stage='window', count=12, last_ms=80.5, p50_ms=75.25,
                                                       p99_ms=140.0)])),
    ('groupforward_msgs/srv/Refer_Request', T('groupforward_msgs/srv/Refer_Request')(
        expression='the trash bin near the cabinet', use_view_pose=True, view_pose=pose(0.5), max_targets=0,
        reasoner='builtin')),
    ('groupforward_msgs/srv/Refer_Response', T('groupforward_msgs/srv/Refer_Response')(
        success=True, message='', instance_ids=['trash_bin_2'], confidences=np.array([0.75], dtype=np.float32),
        poses=[pose(1.0)], boxes=[box], target_cloud=cloud, view_masks=[masks], candidates=[candidate],
        reasoner_used='builtin', trace='target=trash bin; anchor=cabinet')),
    ('groupforward_msgs/srv/GetInstance_Response', T('groupforward_msgs/srv/GetInstance_Response')(
        found=True, instance=instance, node=node)),
]


def plain(value):
    """The message as JSON-able data, field names as in the .msg files."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list):
        return [plain(v) for v in value]
    if dataclasses.is_dataclass(value):
        # Constants are class attributes in rosbags; the wire fields come from the type definition.
        _, fields = ts.fielddefs[value.__msgtype__]
        return {name: plain(getattr(value, name)) for name, _ in fields}
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    return value


golden = {'cases': [], 'hashes': {}}
for type_name, message in cases:
    golden['cases'].append({
        'type': type_name,
        'cdr_hex': bytes(ts.serialize_cdr(message, type_name)).hex(),
        'json': plain(message),
    })
# service_msgs/msg/ServiceEventInfo is left out: rosbags hashes its char[16] as FIELD_TYPE_CHAR, while
# rosidl maps .msg char to uint8; the Rust hash of it is checked through the known AddTwoInts hash.
for type_name in sorted(set(list(add) + [
        'builtin_interfaces/msg/Time', 'std_msgs/msg/Header', 'std_msgs/msg/String', 'sensor_msgs/msg/Image',
        'sensor_msgs/msg/CompressedImage', 'sensor_msgs/msg/CameraInfo', 'sensor_msgs/msg/PointCloud2',
        'geometry_msgs/msg/TransformStamped', 'tf2_msgs/msg/TFMessage', 'visualization_msgs/msg/Marker',
        'visualization_msgs/msg/MarkerArray', 'geometry_msgs/msg/Pose'])):
    golden['hashes'][type_name] = ts.hash_rihs01(type_name)

OUT.write_text(json.dumps(golden, indent=1, sort_keys=True) + '\n')
print(f'wrote {len(golden["cases"])} vectors and {len(golden["hashes"])} hashes to {OUT}')
