"""The ROS 2 message types the bridge speaks, as Cyclone DDS IDL structs with ROS 2's wire names.

Each class follows its stock ROS 2 definition (Humble, Jazzy and Kilted agree on all of these)
field by field, in order, with the same IDL types: ``builtin_interfaces/Time`` is ``int32 sec,
uint32 nanosec``; ``uint8[]`` is ``sequence<uint8>``; ``float64[9]`` is ``double[9]``; ``byte``
is ``octet``. Type names are rmw_cyclonedds_cpp's and rmw_fastrtps_cpp's:
``<package>::msg::dds_::<Type>_``. The structs are final and unkeyed, so they serialise as plain
CDR (XCDR1) like ROS 2's; :mod:`aes_planner.ros2.dds` also pins the XCDR1 data representation in
every reader's and writer's QoS, as rmw_cyclonedds does (``allowed_data_representation = XCDR1``).

``uint8[]`` fields (image bytes) take and give ``bytes`` through a byte-copy codec that keeps the
declared IDL type (so the XTypes type information stays ``sequence<uint8>``): the stock codec
packs a Python int per byte, ~120 ms for a 640x480 RGB image.

``aes_planner_msgs/msg/ViewSuggestion`` and ``ViewCandidate`` are this package's own ROS 2
interface; their ``.msg`` files are in ``ros2/aes_planner_msgs/msg/`` of the repository and must
stay field-for-field identical to the classes here (a test compares them).
"""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.idl._machinery import Machine, PlainCdrV2SequenceOfPrimitiveMachine

__all__ = ["ROS_TYPES", "ros_type_name", "dds_type_name"]


def _octets(cls):
    """Swap the per-int codec of every ``sequence<uint8>`` member of ``cls`` for a byte copy."""
    idl = cls.__idl__
    idl.populate()
    for machine in (idl.v1_machine, idl.v2_machine):
        for name, member in list(machine.members_machines.items()):
            if isinstance(member, PlainCdrV2SequenceOfPrimitiveMachine) and member.code == "B":
                machine.members_machines[name] = _OctetSequence()
    return cls


class _OctetSequence(Machine):
    """``sequence<uint8>`` as bytes: a uint32 count, then the bytes (alignment 1)."""

    alignment = 4

    def __init__(self):  # Machine.__init__ wants a primitive type; this one has no other state
        pass

    def serialize(self, buffer, value, serialize_kind=None, key_enabled=None):
        buffer.align(4)
        view = memoryview(value).cast("B") if not isinstance(value, (list, tuple)) else bytes(value)
        buffer.write("I", 4, len(view))
        buffer.write_bytes(view)

    def deserialize(self, buffer, deserialize_kind=None, key_enabled=None):
        buffer.align(4)
        n = buffer.read("I", 4)
        return buffer.read_bytes(n)

    def key_scan(self):  # pragma: no cover - ROS 2 types are unkeyed
        from cyclonedds.idl._machinery import KeyScanner

        return KeyScanner.infinity()

    def default_initialize(self):
        return b""


# -- builtin_interfaces, std_msgs -------------------------------------------------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str = ""
    size: t.uint32 = 0
    stride: t.uint32 = 0


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: t.sequence[MultiArrayDimension] = field(default_factory=list)
    data_offset: t.uint32 = 0


@dataclass
class Float64MultiArray(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: t.sequence[t.float64] = field(default_factory=list)


# -- geometry_msgs, tf2_msgs --------------------------------------------------------------------


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class PoseArray(IdlStruct, typename="geometry_msgs::msg::dds_::PoseArray_"):
    header: Header = field(default_factory=Header)
    poses: t.sequence[Pose] = field(default_factory=list)


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: t.sequence[TransformStamped] = field(default_factory=list)


# -- sensor_msgs --------------------------------------------------------------------------------


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: t.sequence[str] = field(default_factory=list)
    position: t.sequence[t.float64] = field(default_factory=list)
    velocity: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)


@_octets
@dataclass
class CompressedImage(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
    header: Header = field(default_factory=Header)
    format: str = ""
    data: t.sequence[t.uint8] = b""


@_octets
@dataclass
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header = field(default_factory=Header)
    height: t.uint32 = 0
    width: t.uint32 = 0
    encoding: str = ""
    is_bigendian: t.uint8 = 0
    step: t.uint32 = 0
    data: t.sequence[t.uint8] = b""


@dataclass
class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
    x_offset: t.uint32 = 0
    y_offset: t.uint32 = 0
    height: t.uint32 = 0
    width: t.uint32 = 0
    do_rectify: bool = False


def _zeros(n: int):
    return field(default_factory=lambda: [0.0] * n)


@dataclass
class CameraInfo(IdlStruct, typename="sensor_msgs::msg::dds_::CameraInfo_"):
    header: Header = field(default_factory=Header)
    height: t.uint32 = 0
    width: t.uint32 = 0
    distortion_model: str = ""
    d: t.sequence[t.float64] = field(default_factory=list)
    k: t.array[t.float64, 9] = _zeros(9)
    r: t.array[t.float64, 9] = _zeros(9)
    p: t.array[t.float64, 12] = _zeros(12)
    binning_x: t.uint32 = 0
    binning_y: t.uint32 = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)


# -- diagnostic_msgs, trajectory_msgs -----------------------------------------------------------


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: t.byte = 0  # OK=0 WARN=1 ERROR=2 STALE=3
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: t.sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header = field(default_factory=Header)
    status: t.sequence[DiagnosticStatus] = field(default_factory=list)


@dataclass
class JointTrajectoryPoint(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectoryPoint_"):
    positions: t.sequence[t.float64] = field(default_factory=list)
    velocities: t.sequence[t.float64] = field(default_factory=list)
    accelerations: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)
    time_from_start: Duration = field(default_factory=Duration)


@dataclass
class JointTrajectory(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectory_"):
    header: Header = field(default_factory=Header)
    joint_names: t.sequence[str] = field(default_factory=list)
    points: t.sequence[JointTrajectoryPoint] = field(default_factory=list)


# -- rmw_dds_common: the ROS 2 graph (``ros_discovery_info``) ----------------------------------
# Gid is char[16] from Iron on (Jazzy, Kilted) and char[24] in Humble: two structs of one name.


@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: t.array[t.uint8, 16] = field(default_factory=lambda: [0] * 16)


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: t.bounded_str[256] = "/"
    node_name: t.bounded_str[256] = ""
    reader_gid_seq: t.sequence[Gid] = field(default_factory=list)
    writer_gid_seq: t.sequence[Gid] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: t.sequence[NodeEntitiesInfo] = field(default_factory=list)


@dataclass
class GidHumble(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: t.array[t.uint8, 24] = field(default_factory=lambda: [0] * 24)


@dataclass
class NodeEntitiesInfoHumble(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: t.bounded_str[256] = "/"
    node_name: t.bounded_str[256] = ""
    reader_gid_seq: t.sequence[GidHumble] = field(default_factory=list)
    writer_gid_seq: t.sequence[GidHumble] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfoHumble(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: GidHumble = field(default_factory=GidHumble)
    node_entities_info_seq: t.sequence[NodeEntitiesInfoHumble] = field(default_factory=list)


# -- aes_planner_msgs (ros2/aes_planner_msgs/msg/*.msg) -----------------------------------------


@dataclass
class ViewCandidate(IdlStruct, typename="aes_planner_msgs::msg::dds_::ViewCandidate_"):
    rank: t.uint32 = 0
    score: t.float64 = 0.0
    coverage: t.float64 = 0.0
    pose: Pose = field(default_factory=Pose)
    yaw: t.float64 = 0.0
    pitch: t.float64 = 0.0
    has_joints: bool = False
    pan: t.float64 = 0.0
    tilt: t.float64 = 0.0
    term_names: t.sequence[str] = field(default_factory=list)
    term_values: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class ViewSuggestion(IdlStruct, typename="aes_planner_msgs::msg::dds_::ViewSuggestion_"):
    header: Header = field(default_factory=Header)
    sequence_number: t.uint64 = 0
    field_version: t.uint64 = 0
    mode: t.uint8 = 0  # MODE_RIG=0 MODE_FREE=1
    kind: t.uint8 = 0  # KIND_SEARCH_RESULT=0 KIND_WAYPOINT=1
    search_latency_s: t.float64 = 0.0
    candidates: t.sequence[ViewCandidate] = field(default_factory=list)
    has_covered_fraction: bool = False
    covered_fraction: t.float64 = 0.0
    explore: t.sequence[ViewCandidate, 1] = field(default_factory=list)  # ViewCandidate[<=1]: optional


#: "pkg/msg/Type" -> IDL class
ROS_TYPES: dict[str, type] = {
    f"{cls.__idl_typename__.split('::')[0]}/msg/{cls.__idl_typename__.split('::')[-1][:-1]}": cls
    for cls in (
        Time,
        Duration,
        Header,
        MultiArrayDimension,
        MultiArrayLayout,
        Float64MultiArray,
        Point,
        Vector3,
        Quaternion,
        Pose,
        PoseStamped,
        PoseArray,
        Transform,
        TransformStamped,
        TFMessage,
        JointState,
        CompressedImage,
        Image,
        RegionOfInterest,
        CameraInfo,
        KeyValue,
        DiagnosticStatus,
        DiagnosticArray,
        JointTrajectoryPoint,
        JointTrajectory,
        ViewCandidate,
        ViewSuggestion,
    )
}


def ros_type_name(cls: type) -> str:
    """``sensor_msgs::msg::dds_::Image_`` -> ``sensor_msgs/msg/Image``."""
    pkg, _, _, name = cls.__idl_typename__.split("::")
    return f"{pkg}/msg/{name[:-1]}"


def dds_type_name(ros_name: str) -> str:
    """``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_`` (rmw_cyclonedds_cpp's naming)."""
    pkg, _, name = ros_name.split("/")
    return f"{pkg}::msg::dds_::{name}_"
