"""RIHS01 hashes of ROS 2 service types, computed with rosbags' type-description hashing.

rosbags hashes messages only. A service's type description (rosidl) is a structure with three
nested fields, request_message, response_message and event_message, where the event message is
(service_msgs/ServiceEventInfo info, Request[<=1] request, Response[<=1] response). rosbags' Jazzy
store files ServiceEventInfo's `char[16] client_gid` as FIELD_TYPE_CHAR where rosidl, which maps a
.msg `char` to uint8, hashes uint8: the event info is redeclared with uint8 here. The construction is
checked against a hash published by ROS 2 (example_interfaces/srv/AddTwoInts) before it is trusted.
"""

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

EVENT_INFO = 'service_msgs/msg/ServiceEventInfo'
EVENT_INFO_MSG = """uint8 REQUEST_SENT = 0
uint8 REQUEST_RECEIVED = 1
uint8 RESPONSE_SENT = 2
uint8 RESPONSE_RECEIVED = 3
uint8 event_type
builtin_interfaces/Time stamp
uint8[16] client_gid
int64 sequence_number
"""
ADD_TWO_INTS = 'RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a'


def _referenced(source, names):
    """Every type `names` refer to, transitively, with its definition in `source`."""
    out, stack = {}, list(names)
    while stack:
        name = stack.pop()
        if name in out:
            continue
        out[name] = source.fielddefs[name]
        for _, desc in source.fielddefs[name][1]:
            node = desc[1][0] if desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE) else desc
            if node[0] == Nodetype.NAME:
                stack.append(node[1])
    return out


def service_hash(source, service):
    """RIHS01 of `service` ('pkg/srv/Name'), whose `_Request` and `_Response` halves are in the rosbags
    typestore `source`."""
    request, response, event = f'{service}_Request', f'{service}_Response', f'{service}_Event'
    types = _referenced(source, [request, response])
    types.pop(EVENT_INFO, None)
    types.update(get_types_from_msg(EVENT_INFO_MSG, EVENT_INFO))
    types.update(_referenced(source, ['builtin_interfaces/msg/Time']))
    types[event] = ([], [
        ('info', (Nodetype.NAME, EVENT_INFO)),
        ('request', (Nodetype.SEQUENCE, ((Nodetype.NAME, request), 1))),
        ('response', (Nodetype.SEQUENCE, ((Nodetype.NAME, response), 1))),
    ])
    types[service] = ([], [
        ('request_message', (Nodetype.NAME, request)),
        ('response_message', (Nodetype.NAME, response)),
        ('event_message', (Nodetype.NAME, event)),
    ])
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store.hash_rihs01(service)


def add_two_ints_hash():
    """The construction applied to example_interfaces/srv/AddTwoInts, whose hash ROS 2 publishes."""
    store = get_typestore(Stores.ROS2_JAZZY)
    halves = {}
    for part, text in (('Request', 'int64 a\nint64 b\n'), ('Response', 'int64 sum\n')):
        (definition,) = get_types_from_msg(text, f'example_interfaces/msg/AddTwoInts_{part}').values()
        halves[f'example_interfaces/srv/AddTwoInts_{part}'] = definition
    store.register(halves)
    return service_hash(store, 'example_interfaces/srv/AddTwoInts')
