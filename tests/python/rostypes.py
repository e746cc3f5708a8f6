"""A rosbags typestore with every type groupforward speaks (ROS 2 Jazzy + vision_msgs + groupforward_msgs).

rosbags is the independent implementation the project checks its CDR, hashes and bags against.
"""

from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

ROS_DIR = Path(__file__).resolve().parents[2] / 'msgs' / 'ros'


def typestore():
    ts = get_typestore(Stores.ROS2_JAZZY)
    add = {}
    for path in sorted((ROS_DIR / 'upstream' / 'vision_msgs' / 'msg').glob('*.msg')):
        add.update(get_types_from_msg(path.read_text(), f'vision_msgs/msg/{path.stem}'))
    for path in sorted((ROS_DIR / 'groupforward_msgs' / 'msg').glob('*.msg')):
        add.update(get_types_from_msg(path.read_text(), f'groupforward_msgs/msg/{path.stem}'))
    for path in sorted((ROS_DIR / 'groupforward_msgs' / 'srv').glob('*.srv')):
        request, response = path.read_text().split('\n---\n')
        # rosbags files messages under pkg/msg/; resolve names there, then register under pkg/srv/.
        for part, text in (('Request', request), ('Response', response)):
            (definition,) = get_types_from_msg(text, f'groupforward_msgs/msg/{path.stem}_{part}').values()
            add[f'groupforward_msgs/srv/{path.stem}_{part}'] = definition
    ts.register(add)
    return ts
