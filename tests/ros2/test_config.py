"""Bridge and DDS configuration: ROS 2's environment variables, the localhost default, clear errors."""

from __future__ import annotations

import pytest

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")

from aes_planner.cli import main
from aes_planner.config import ConfigError, from_dict
from aes_planner.ros2 import idl
from aes_planner.ros2.bridge import Ros2BridgeConfig
from aes_planner.ros2.dds import DdsConfig, DdsError, cyclone_config, resolve_domain_id, resolve_range


def test_domain_id_comes_from_the_config_else_ros_domain_id_else_zero():
    assert resolve_domain_id(DdsConfig(domain_id=7), {"ROS_DOMAIN_ID": "3"}) == 7
    assert resolve_domain_id(DdsConfig(), {"ROS_DOMAIN_ID": "3"}) == 3
    assert resolve_domain_id(DdsConfig(), {}) == 0
    for bad in ("233", "x", "-1"):
        with pytest.raises(DdsError, match="ROS_DOMAIN_ID"):
            resolve_domain_id(DdsConfig(), {"ROS_DOMAIN_ID": bad})


def test_discovery_defaults_to_loopback_and_honours_the_ros_variables():
    assert resolve_range(DdsConfig(), {}) == ("loopback", ())
    assert resolve_range(DdsConfig(), {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})[0] == "localhost"
    assert resolve_range(DdsConfig(), {"ROS_LOCALHOST_ONLY": "1"})[0] == "localhost"
    assert resolve_range(DdsConfig(), {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_STATIC_PEERS": "a;b"}) == (
        "subnet",
        ("a", "b"),
    )
    assert resolve_range(DdsConfig(discovery_range="off"), {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"})[0] == "off"
    with pytest.raises(DdsError, match="ROS_AUTOMATIC_DISCOVERY_RANGE"):
        resolve_range(DdsConfig(), {"ROS_AUTOMATIC_DISCOVERY_RANGE": "everywhere"})


def test_loopback_config_is_rmw_cyclonedds_fragment_on_the_loopback_interface_then_the_users_uri():
    xml = cyclone_config("loopback", (), False, None)
    for part in (
        '<NetworkInterface address="127.0.0.1"/>',
        "<AllowMulticast>false</AllowMulticast>",
        "<ParticipantIndex>auto</ParticipantIndex>",
        "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>",
        '<Peer address="127.0.0.1"/>',
    ):
        assert part in xml
    with_uri = cyclone_config("loopback", (), False, "file:///etc/cyclone.xml")
    assert with_uri.endswith(",file:///etc/cyclone.xml") and "NetworkInterface" not in with_uri
    # localhost: exactly what rmw_cyclonedds_cpp generates for ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
    assert cyclone_config("localhost", (), False, None) == (
        "<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast></General><Discovery>"
        "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
        '<Peers><Peer address="localhost"/></Peers></Discovery></Domain></CycloneDDS>'
    )
    assert cyclone_config("system_default", (), True, None) == ""


def test_reaching_beyond_the_machine_needs_the_explicit_option():
    for rng, peers in (("subnet", ()), ("system_default", ()), ("localhost", ("10.0.0.5",))):
        with pytest.raises(DdsError, match="allow-remote-dds"):
            cyclone_config(rng, peers, False, None)
    assert '<Peer address="10.0.0.5"/>' in cyclone_config("subnet", ("10.0.0.5",), True, None)


def test_bad_bridge_config_names_the_key():
    for data, key in (
        ({"outbound": ["suggestion", "everything"]}, "outbound[1]"),
        ({"qos": {"image": "fast"}}, "qos.image"),
        ({"topics": {"suggestion": "/bad topic"}}, "topics.suggestion"),
        ({"topics": {"nope": "/x"}}, "topics.nope"),
        ({"joint_names": ["pan", "pan"]}, "joint_names"),
        ({"world_frame": ""}, "world_frame"),
        ({"dds": {"domain_id": 300}}, "dds.domain_id"),
        ({"inbound_typo": True}, "inbound_typo"),
    ):
        with pytest.raises(ConfigError) as exc:
            from_dict(Ros2BridgeConfig, data)
        assert exc.value.key == key, (data, exc.value)


def test_cli_errors_are_one_line(tmp_path, capsys):
    bad = tmp_path / "bridge.yaml"
    bad.write_text("qos: {image: fast}\n")
    assert main(["ros2", "bridge", "--config", str(bad), "--duration", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "qos.image" in err[0]
    assert main(["ros2", "bridge", "--scene", "nowhere:1", "--duration", "1"]) == 2
    assert "nowhere" in capsys.readouterr().err


def test_the_shipped_msg_files_match_the_wire_structs():
    """aes_planner_msgs: field names and order of the .msg files are the IDL structs' (the DDS test
    peers parse the .msg files, so a difference would also fail the round trips)."""
    from tests.ros2.stock import typestore

    for name, cls in (
        ("aes_planner_msgs/msg/ViewSuggestion", idl.ViewSuggestion),
        ("aes_planner_msgs/msg/ViewCandidate", idl.ViewCandidate),
    ):
        fields = [f for f, _ in typestore().fielddefs[name][1]]
        assert fields == list(cls.__dataclass_fields__), name


def test_humble_jazzy_and_kilted_define_every_bridged_type_alike():
    """The round trips run against Jazzy's definitions; Humble's and Kilted's are the same for every
    type the bridge speaks, so the same bytes serve all three."""
    from rosbags.typesys import Stores, get_typestore

    stores = {s: get_typestore(s) for s in (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY, Stores.ROS2_KILTED)}
    for name in idl.ROS_TYPES:
        if name.startswith("aes_planner_msgs/"):
            continue
        defs = {s: ts.fielddefs[name][1] for s, ts in stores.items()}
        assert len({repr(d) for d in defs.values()}) == 1, name


IDL_KEYWORDS = set(
    """abstract any alias attribute bitfield bitmask bitset boolean case char component connector const
    consumes context custom default double exception emits enum eventtype factory false finder fixed
    float getraises getter home import in inout interface local long manages map mirrorport module
    multiple native object octet oneway out primarykey private port porttype provides public publishes
    raises readonly setraises setter sequence short string struct supports switch true truncatable
    typedef typeid typename typeprefix unsigned union uses valuebase valuetype void wchar wstring int8
    uint8 int16 int32 int64 uint16 uint32 uint64""".split()
)


def test_aes_planner_msgs_field_names_are_no_idl_cpp_or_python_keywords():
    """rosidl turns .msg files into IDL (keywords compare case-insensitively there, OMG IDL 4.2
    7.2.4) and C++ and Python classes."""
    import keyword

    from tests.ros2.stock import typestore

    cpp = {"class", "delete", "new", "operator", "template", "this", "namespace", "register", "default"}
    for name in ("aes_planner_msgs/msg/ViewSuggestion", "aes_planner_msgs/msg/ViewCandidate"):
        for field, _ in typestore().fielddefs[name][1]:
            assert field.lower() not in IDL_KEYWORDS and field not in cpp and not keyword.iskeyword(field), field


def test_graph_info_structs_are_each_releases_ros_discovery_info():
    from rosbags.typesys import Stores, get_typestore

    name = "rmw_dds_common/msg/ParticipantEntitiesInfo"
    for store, info_t, node_t, gid_t, size in (
        (Stores.ROS2_JAZZY, idl.ParticipantEntitiesInfo, idl.NodeEntitiesInfo, idl.Gid, 16),
        (Stores.ROS2_KILTED, idl.ParticipantEntitiesInfo, idl.NodeEntitiesInfo, idl.Gid, 16),
        (Stores.ROS2_HUMBLE, idl.ParticipantEntitiesInfoHumble, idl.NodeEntitiesInfoHumble, idl.GidHumble, 24),
    ):
        gid = gid_t(list(range(size)))
        raw = info_t(gid, [node_t("/", "aes_planner_bridge", [gid], [gid, gid])]).serialize(use_version_2=False)
        msg = get_typestore(store).deserialize_cdr(raw, name)
        (node,) = msg.node_entities_info_seq
        assert list(msg.gid.data) == list(range(size)) and node.node_name == "aes_planner_bridge"
        assert len(node.reader_gid_seq) == 1 and len(node.writer_gid_seq) == 2, store
