"""The node on native ROS 2, against real ROS 2 (rclpy, rmw_fastrtps from the PyPI wheels).

An rclpy node plays a sim bag's frames, camera info, depth and TF into the ROS 2 graph (the bag's
CDR bytes as they are, at the recorded rate), while `groupforward run` with `transport: ros2`
maps them. Then, from rclpy with the generated message types: the ROS graph shows the node, its
status counts the frames (at most one lost to discovery), `~/list_instances` lists what it mapped,
`~/instances` (vision_msgs/Detection3DArray) and `~/markers` arrive and decode, `~/get_instance`,
`~/refer`, `~/save_map` and `~/load_map` answer, and a refused request says success false and why.
Last, a second node on the zenoh transport restores the saved map and answers every referring
expression with the same instances (the live map itself depends on which windows a busy worker
dropped, so two live runs are not compared).

Run by `make ros2-test` (which prepares the environment): python ros2_end_to_end.py --node BIN
--bag DIR. Exits non-zero with the failed check.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from mcap.reader import make_reader
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from groupforward_msgs.msg import NodeStatus
from groupforward_msgs.srv import GetInstance, ListInstances, LoadMap, Refer, SaveMap
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

# The default config's colour topic, which `sim record` writes too.
COLOUR_TOPIC = "/camera/color/image_raw"

TYPES = {
    "sensor_msgs/msg/Image": Image,
    "sensor_msgs/msg/CompressedImage": CompressedImage,
    "sensor_msgs/msg/CameraInfo": CameraInfo,
    "tf2_msgs/msg/TFMessage": TFMessage,
}


def read_bag(bag: Path):
    """(topic, type name, log time ns, CDR bytes) of every message a node subscribes to."""
    files = sorted(bag.glob("*.mcap")) if bag.is_dir() else [bag]
    out = []
    for file in files:
        with open(file, "rb") as stream:
            for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True):
                if channel.topic.startswith("/gt/") or schema.name not in TYPES:
                    continue
                out.append((channel.topic, schema.name, message.log_time, bytes(message.data)))
    out.sort(key=lambda m: m[2])
    return out


def label(instance) -> str:
    return instance.hypotheses[0].class_id if instance.hypotheses else "unknown"


def call(node: Node, client, request, timeout: float = 20.0):
    if not client.wait_for_service(timeout_sec=timeout):
        raise AssertionError(f"service {client.srv_name} not available")
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    if not future.done():
        raise AssertionError(f"service {client.srv_name} did not answer in {timeout} s")
    return future.result()


def ask_over_zenoh(binary: str, work: Path, snapshot: Path, expressions) -> dict:
    """Each expression's answer (sorted ids, or None when refused) from a zenoh node on `snapshot`."""
    port = 17447 + os.getpid() % 1000
    endpoint = f"tcp/127.0.0.1:{port}"
    config = work / "zenoh.yaml"
    config.write_text(
        "transport: zenoh\n"
        f"zenoh:\n  listen: [{endpoint}]\n  connect: []\n"
        f"map:\n  file: {snapshot}\n  restore_on_start: true\n  save_on_exit: false\n"
    )
    log = open(work / "zenoh_node.log", "w")
    node = subprocess.Popen([binary, "run", "--config", str(config), "--duration-secs", "120"],
                            stdout=log, stderr=subprocess.STDOUT)
    try:
        answers = {}
        for expression in expressions:
            query = [binary, "query", expression, "--connect", endpoint, "--reasoner", "builtin"]
            for _ in range(20):  # the node may still be starting
                done = subprocess.run(query, capture_output=True, text=True, timeout=60)
                answered = done.returncode == 0
                refused = done.returncode == 1 and "no answer" in done.stdout
                if answered or refused:
                    break
                time.sleep(0.5)
            assert answered or refused, f"query '{expression}' failed: {done.stderr}"
            ids = [line.split()[0] for line in done.stdout.splitlines() if line.startswith("  inst_")]
            answers[expression] = sorted(ids) if answered else None
        return answers
    finally:
        node.terminate()
        node.wait(timeout=20)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--node", required=True, help="groupforward binary built with --features ros2")
    parser.add_argument("--bag", required=True, type=Path)
    parser.add_argument(
        "--expressions",
        nargs="+",
        default=["the trash bin", "the table", "both chairs", "the chair closest to the trash bin"],
    )
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--extra-config", default="", help="YAML appended to the node's config")
    args = parser.parse_args()

    messages = read_bag(args.bag)
    assert messages, f"no camera messages in {args.bag}"
    work = Path(tempfile.mkdtemp(prefix="gf-ros2-"))
    (work / "maps").mkdir()
    config = work / "node.yaml"
    config.write_text(
        "transport: ros2\n"
        f"map:\n  directory: {work / 'maps'}\n" + args.extra_config
    )
    log = open(work / "node.log", "w")
    node_process = subprocess.Popen(
        [args.node, "run", "--config", str(config), "--duration-secs", "600"],
        stdout=log,
        stderr=subprocess.STDOUT,
        env={**os.environ, "RUST_LOG": os.environ.get("RUST_LOG", "info")},
    )
    rclpy.init()
    player = Node("gf_bag_player")
    try:
        return run_checks(args, player, messages, node_process, work)
    except AssertionError as failure:
        print(f"FAILED: {failure}", file=sys.stderr)
        print(f"node log: {work / 'node.log'}", file=sys.stderr)
        return 1
    finally:
        node_process.terminate()
        try:
            node_process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            node_process.kill()
        player.destroy_node()
        rclpy.shutdown()


def run_checks(args, player: Node, messages, node_process, work: Path) -> int:
    received: dict[str, list] = {"status": [], "instances": [], "markers": []}
    player.create_subscription(NodeStatus, "/groupforward/status", received["status"].append, 10)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
    player.create_subscription(
        Detection3DArray, "/groupforward/instances", received["instances"].append, latched
    )
    player.create_subscription(MarkerArray, "/groupforward/markers", received["markers"].append, latched)

    publishers = {}
    for topic, type_name, _, _ in messages:
        if topic in publishers:
            continue
        if topic == "/tf_static":
            qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        else:
            qos = QoSProfile(depth=10)
        publishers[topic] = player.create_publisher(TYPES[type_name], topic, qos)

    # Discovery: wait until the node subscribes to every camera topic.
    deadline = time.monotonic() + 30
    while any(p.get_subscription_count() == 0 for p in publishers.values()):
        assert node_process.poll() is None, "the node exited during discovery"
        assert time.monotonic() < deadline, "the node did not subscribe to the camera topics in 30 s"
        rclpy.spin_once(player, timeout_sec=0.1)

    start_wall, start_bag = time.monotonic(), messages[0][2]
    for topic, _, stamp, data in messages:
        if args.rate > 0:
            due = start_wall + (stamp - start_bag) / 1e9 / args.rate
            while time.monotonic() < due:
                rclpy.spin_once(player, timeout_sec=max(0.0, min(0.01, due - time.monotonic())))
        publishers[topic].publish(data)
    print(f"published {len(messages)} messages on {len(publishers)} topics")

    # The node finishes its last windows; the outputs publish at most twice a second.
    list_client = player.create_client(ListInstances, "/groupforward/list_instances")
    deadline = time.monotonic() + 60
    instances = []
    while time.monotonic() < deadline:
        pause = time.monotonic() + 0.5
        while time.monotonic() < pause:
            rclpy.spin_once(player, timeout_sec=0.1)
        instances = call(player, list_client, ListInstances.Request()).instances
        if instances and received["instances"] and received["instances"][-1].detections:
            break
    assert node_process.poll() is None, "the node exited"
    assert received["status"], "no NodeStatus arrived"
    status = received["status"][-1]
    frames = sum(c.frames_received for c in status.cameras)
    synced = sum(c.frames_synced for c in status.cameras)
    rejected = ", ".join(f"{r.reason} {r.count}" for r in status.rejections) or "none"
    print(f"status: {frames} frames received, {synced} synced, rejected: {rejected}")
    colour = sum(1 for topic, _, _, _ in messages if topic == COLOUR_TOPIC)
    # Best-effort camera topics may lose a frame to discovery, not more (Fast DDS's default
    # shared-memory segment lost up to half of them: launch/ros2/fastdds.xml).
    assert synced >= 0.9 * colour, f"only {synced} of {colour} frames synced (status: {status})"
    assert instances, "list_instances is empty after the bag"
    assert received["instances"], "no Detection3DArray arrived"
    ids = {i.id for i in instances}
    detections = received["instances"][-1].detections
    assert {d.id for d in detections} <= ids, "a detection names no listed instance"
    assert received["markers"], "no MarkerArray arrived"
    print(f"{len(instances)} instances listed: "
          + ", ".join(sorted(f"{i.id} {label(i)}" for i in instances)))

    names = player.get_node_names_and_namespaces()
    assert ("groupforward", "/") in names, f"the ROS graph does not show the node: {names}"

    get_client = player.create_client(GetInstance, "/groupforward/get_instance")
    first = sorted(ids)[0]
    got = call(player, get_client, GetInstance.Request(id=first))
    assert got.found and got.instance.id == first, f"get_instance {first}: {got}"

    refer_client = player.create_client(Refer, "/groupforward/refer")
    ros_answers = {}
    for expression in args.expressions:
        answer = call(player, refer_client, Refer.Request(expression=expression, reasoner="builtin"))
        if answer.success:
            assert set(answer.instance_ids) <= ids, f"refer '{expression}' names an unlisted instance"
            assert len(answer.boxes) == len(answer.instance_ids) == len(answer.confidences)
        ros_answers[expression] = sorted(answer.instance_ids) if answer.success else None
        print(f"refer '{expression}': {ros_answers[expression] or 'refused: ' + answer.message} "
              f"({answer.reasoner_used})")
    assert ros_answers[args.expressions[0]], f"refer '{args.expressions[0]}' found nothing"

    # Save, then load the snapshot back: the same instances.
    save_client = player.create_client(SaveMap, "/groupforward/save_map")
    saved = call(player, save_client, SaveMap.Request(path="ros2.gfmap"))
    assert saved.success, f"save_map: {saved.message}"
    load_client = player.create_client(LoadMap, "/groupforward/load_map")
    loaded = call(player, load_client, LoadMap.Request(path="ros2.gfmap"))
    assert loaded.success, f"load_map: {loaded.message}"
    again = {i.id for i in call(player, list_client, ListInstances.Request()).instances}
    assert again == ids, f"load_map gave {sorted(again)}, saved {sorted(ids)}"
    print(f"save_map / load_map: {len(again)} instances back")

    # A refused request: success false with the node's reason (ROS 2 services have no error reply).
    refused = call(player, load_client, LoadMap.Request(path="../../etc/passwd"))
    assert not refused.success and refused.message, "load_map outside the map directory was not refused"
    print(f"load_map '../../etc/passwd': refused ({refused.message})")

    # The zenoh transport answers the same on the same map: a second node restores the snapshot.
    zenoh_answers = ask_over_zenoh(args.node, work, work / "maps" / "ros2.gfmap", args.expressions)
    for expression in args.expressions:
        assert zenoh_answers[expression] == ros_answers[expression], (
            f"'{expression}': ROS 2 answered {ros_answers[expression]}, "
            f"zenoh {zenoh_answers[expression]}"
        )
    print(f"zenoh transport on the saved map: the same {len(args.expressions)} answers")
    print("ros2 end to end: OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
