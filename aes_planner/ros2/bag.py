"""``aes-planner export rosbag2 RECORDING.mcap OUT_DIR``: a package recording as a rosbag2 folder.

The package's own channels of the recording (:func:`aes_planner.transport.record.read_recording`)
go through the bridge's mapping (:class:`~aes_planner.ros2.outbound.OutboundMapper`) into the
ROS 2 topics and types of the bridge (docs/guides/ros2.md), serialised as ROS 2 CDR by the same IDL
structs the bridge puts on the wire. Each message is logged at its header stamp (its capture or
planning time), or the recording's log time where it has none.

The folder is written by ``rosbags`` (``rosbags.rosbag2.Writer``, MCAP storage, metadata version
8 as Jazzy writes it): ``metadata.yaml`` and ``<OUT_DIR>.mcap`` with profile ``ros2``, schema
encoding ``ros2msg`` (each type's definition with its dependencies after ``=`` lines, from
rosbags' stock Jazzy typestore plus this package's ``aes_planner_msgs``), message encoding
``cdr``, chunked, with message and chunk indexes and a summary, and ``offered_qos_profiles`` in
each channel's metadata and in ``metadata.yaml``. ``ros2 bag info``, ``ros2 bag play`` and
Foxglove open it.
"""

from __future__ import annotations

import logging
from pathlib import Path

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.plausible import MAX_STAMP_S
from aes_planner.messages import MessageError, decode
from aes_planner.paths import new_output_folder

log = logging.getLogger(__name__)

__all__ = ["BagExportError", "export_rosbag2", "ros2_typestore"]

MSG_DIR = Path(__file__).with_name("msg")


class BagExportError(AesPlannerError):
    """The recording cannot be exported (missing, unreadable, output folder exists)."""


def ros2_typestore():
    """rosbags' stock Jazzy typestore with ``aes_planner_msgs`` added from its ``.msg`` files."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    add = {}
    for f in sorted(MSG_DIR.glob("*.msg")):
        add.update(get_types_from_msg(f.read_text(encoding="utf-8"), f"aes_planner_msgs/msg/{f.stem}"))
    ts.register(add)
    return ts


def _qos(profile: str, depth: int):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    reliability = QosReliability.BEST_EFFORT if profile == "sensor_data" else QosReliability.RELIABLE
    durability = QosDurability.TRANSIENT_LOCAL if profile == "latched" else QosDurability.VOLATILE
    zero = QosTime(0, 0)  # rosbag2 writes infinite durations as 0
    return Qos(QosHistory.KEEP_LAST, depth, reliability, durability, zero, zero, QosLiveliness.AUTOMATIC, zero, False)


def export_rosbag2(recording: str | Path, out_dir: str | Path, config=None, rig=None) -> dict[str, int]:
    """Write the rosbag2 folder ``out_dir`` (which must not exist); returns messages per ROS 2 topic.

    ``config``: a :class:`~aes_planner.ros2.bridge.Ros2BridgeConfig` (topics, frames, rig);
    ``rig``: the rig's kinematics (a :class:`~aes_planner.geometry.PanTiltConfig`) for the rig's tf
    links when ``config`` names none (the command line takes it from the run's simulated scene)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from aes_planner.ros2 import idl
    from aes_planner.ros2.bridge import DEPTHS, OUTBOUND, Ros2BridgeConfig
    from aes_planner.ros2.convert import Ros2InputError
    from aes_planner.ros2.outbound import OutboundMapper
    from aes_planner.transport.record import read_recording

    recording, out_dir = Path(recording), Path(out_dir)
    if not recording.is_file():
        raise BagExportError(f"{recording}: no such recording; give the .mcap a run wrote (aes-planner demo --out RUN)")
    new_output_folder(out_dir, "OUT_DIR")
    next(iter(read_recording(recording)), None)  # a clear error for a bad file before the folder exists
    config = config or Ros2BridgeConfig()
    rig = config.rig if config.rig is not None else rig
    links = None
    if rig is not None:
        from aes_planner.ros2.links import RigLinks

        links = RigLinks(rig)
    mapper = OutboundMapper(config, links)
    ts = ros2_typestore()
    counts: dict[str, int] = {}
    rejected = 0
    refused: list[str] = []  # messages with stamps no bag holds (why, the first few)
    mapped = 0
    writer = Writer(out_dir, version=8, storage_plugin=StoragePlugin.MCAP)
    connections: dict[str, object] = {}

    def write(key: str, sample, t_ns: int) -> None:
        if key not in config.outbound:
            return
        conn = connections.get(key)
        if conn is None:
            _, type_name, _ = OUTBOUND[key]
            profile = config.profile(key)
            conn = connections[key] = writer.add_connection(
                config.topic(key),
                type_name,
                typestore=ts,
                serialization_format="cdr",
                offered_qos_profiles=[_qos(profile, DEPTHS.get(key, 1 if profile == "latched" else 10))],
            )
        writer.write(conn, t_ns, sample.serialize(use_version_2=False))
        counts[config.topic(key)] = counts.get(config.topic(key), 0) + 1

    writer.open()
    ok = False
    try:
        first = True
        for _topic, data, log_ns in read_recording(recording):
            try:
                msg = decode(data)
            except MessageError as exc:
                rejected += 1
                log.log(
                    logging.WARNING if rejected <= 3 else logging.DEBUG, "%s: skipped a message: %s", recording, exc
                )
                continue
            try:
                if not 0 <= log_ns <= MAX_STAMP_S * 1e9:
                    raise Ros2InputError(f"log time {log_ns * 1e-9:.6g} s is not a time (0 to {MAX_STAMP_S:.0f} s)")
                samples = [(key, sample, _stamp_ns(sample, log_ns, idl)) for key, sample in mapper.map(msg)]
                if first and samples:
                    for key, sample in mapper.static(log_ns * 1e-9):
                        write(key, sample, log_ns)
                    first = False
            except Ros2InputError as exc:
                refused.append(str(exc))
                log.log(
                    logging.WARNING if len(refused) <= 3 else logging.DEBUG, "%s: refused a message: %s", recording, exc
                )
                continue
            for key, sample, t_ns in samples:
                write(key, sample, t_ns)
                mapped += 1
        if not mapped:
            said = f"; {len(refused)} refused, e.g. {refused[0]}" if refused else ""
            raise BagExportError(
                f"{recording}: holds no message a ROS 2 bag can carry ({rejected} undecodable{said}); "
                "give a recording a run wrote (aes-planner demo --out RUN: RUN/recording.mcap)"
            )
        ok = True
    finally:
        writer.close()
        if not ok:  # no half bag left behind for ros2 bag to choke on
            import shutil

            shutil.rmtree(out_dir, ignore_errors=True)
    if refused:
        log.warning(
            "%s: %d message(s) refused for their stamps (not written), e.g. %s", recording, len(refused), refused[0]
        )
    if rejected:
        log.warning(
            "%s: %d message(s) of types without a ROS 2 mapping or undecodable were skipped", recording, rejected
        )
    return counts


def _stamp_ns(sample, fallback_ns: int, idl) -> int:
    header = getattr(sample, "header", None)
    if header is None and isinstance(sample, idl.TFMessage) and sample.transforms:
        header = sample.transforms[0].header
    if header is None:
        return fallback_ns
    ns = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
    return ns if ns > 0 else fallback_ns
